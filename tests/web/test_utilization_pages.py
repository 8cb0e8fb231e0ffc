"""The utilization page in Debian's Chromium (Playwright) at 1280×800 and 768 wide, against
the timeline of ``utilization_shop``: the percentages worked out by hand are on the page, the
Gantt draws the states in their andon colours in the shop's local time, nothing overflows
its box and no name, date or number wraps inside a word. Screenshots go to
``tests/artifacts/screenshots`` (gitignored) for a person to look at."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest

from tests.peers import require_module

require_module("playwright.sync_api")

from tests.web.browser import ARTIFACTS, chromium, watched_context, watched_page  # noqa: E402
from tests.web.utilization_shop import UtilShop, serve_util_shop  # noqa: E402

WIDTHS = [(1280, 800), (768, 1024)]

# Elements whose content overflows their own box (scroll containers excepted: a wide table
# scrolls inside its frame), and text that wraps inside a word in names, times and figures.
OVERFLOW_JS = """() => {
  const out = [];
  const scrolls = e => ['auto', 'scroll'].includes(getComputedStyle(e).overflowX);
  for (const e of document.querySelectorAll('main *')) {
    if (e.closest('svg') && e.tagName !== 'svg') continue;
    const r = e.getBoundingClientRect();
    if (r.width === 0) continue;
    if (!scrolls(e) && e.scrollWidth > e.clientWidth + 1 && e.clientWidth > 0
        && getComputedStyle(e).display !== 'inline')
      out.push('overflows: ' + e.tagName + '.' + e.className + ' '
               + (e.textContent || '').slice(0, 40));
    const box = e.parentElement.getBoundingClientRect();
    if (!e.parentElement.closest('.table-wrap') && r.right > box.right + 1
        && !scrolls(e.parentElement) && e.parentElement.tagName !== 'svg')
      out.push('sticks out: ' + e.tagName + '.' + e.className + ' '
               + (e.textContent || '').slice(0, 40));
  }
  if (document.documentElement.scrollWidth > window.innerWidth)
    out.push('page wider than the window: ' + document.documentElement.scrollWidth);
  return out;
}"""
# A text node of a name, time or figure that takes more than one line box.
WRAPS_JS = """(selector) => [...document.querySelectorAll(selector)]
  .filter(e => { const r = document.createRange(); r.selectNodeContents(e);
                 const lines = new Set([...r.getClientRects()].map(x => Math.round(x.top)));
                 return lines.size > 1; })
  .map(e => e.textContent.trim())"""


@pytest.fixture(scope="module")
def shop(tmp_path_factory: pytest.TempPathFactory) -> Iterator[UtilShop]:
    with serve_util_shop(tmp_path_factory.mktemp("util-pages")) as served:
        yield served


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    with chromium() as b:
        yield b


def _open(
    browser: Any, shop: UtilShop, size: tuple[int, int], query: str, path: str = "/utilization"
) -> tuple[Any, list[str]]:
    problems: list[str] = []
    page = watched_page(watched_context(browser, shop.url, problems, size), problems)
    page.goto(f"{shop.url}{path}?{query}")
    page.get_by_label("User name").fill("viewer")
    page.get_by_label("Password").fill("viewer-secret-1")
    page.get_by_role("button", name="Log in").click()
    page.wait_for_url(f"{shop.url}{path}?{query}")
    return page, problems


@pytest.mark.parametrize("size", WIDTHS, ids=lambda s: f"{s[0]}")
def test_one_day_per_shift_shows_the_known_percentages(
    browser: Any, shop: UtilShop, size: tuple[int, int]
) -> None:
    page, problems = _open(browser, shop, size, "from=2026-01-05&to=2026-01-05&group=shift")
    # the table: over the day's 18 h of shifts, and over the recorded time
    assert page.locator('[data-util="mill-1"]').inner_text() == "25.0 %"
    assert page.locator('[data-recorded="mill-1"]').inner_text() == "50.0 %"
    assert page.locator('[data-util="vf2-long-name-1"]').inner_text() == "22.2 %"
    assert page.locator('[data-recorded="vf2-long-name-1"]').inner_text() == "66.7 %"
    assert page.locator('[data-util="lathe-3"]').inner_text() == "0.0 %"
    assert page.locator('[data-recorded="lathe-3"]').inner_text() == "–"
    # the bars per shift: mill-1's early shift ran 4.5 h of 8 h
    mill_bars = page.locator(".util-bars li").filter(has_text="mill-1")
    assert "56.3 %" in mill_bars.inner_text()
    assert "Mon 05 early" in mill_bars.inner_text()
    # the Gantt: mill-1 ran from 07:00 local (CET) in andon green
    strip = page.get_by_role("img", name="mill-1:", exact=False).first
    assert "running from 2026-01-05 07:00 CET" in strip.get_attribute("aria-label")
    fills = page.eval_on_selector_all(
        ".gantt-strip rect.st-running, .gantt-strip rect.st-alarm, .gantt-strip rect.st-ready",
        "els => [...new Set(els.map(e => e.classList[0] + ' ' + getComputedStyle(e).fill))]",
    )
    assert sorted(fills) == [
        "st-alarm rgb(208, 49, 45)",
        "st-ready rgb(151, 138, 100)",  # dark enough beside no record
        "st-running rgb(47, 158, 68)",
    ]
    # times in the shop's zone, named
    assert "times in Europe/Berlin" in page.locator(".util-note").inner_text()
    stops = page.locator("table.util-list").first.inner_text()
    assert "2026-01-05 13:00 CET" in stops
    assert "1010 SPINDLE OVERLOAD" in stops
    # the legend names every state
    legend = page.locator(".util-legend").inner_text().split("\n")
    assert [x.strip() for x in legend if x.strip()] == [
        "running",
        "ready",
        "stopped",
        "alarm",
        "offline",
        "unknown",
        "no record",
    ]
    assert page.evaluate(OVERFLOW_JS) == []
    wraps = page.evaluate(
        WRAPS_JS,
        ".gantt-name, .util-table th[scope=row], .util-table td, .util-list td.machine, "
        ".util-list td.nowrap, .util-list td.num, .util-bars h3 a",
    )
    assert wraps == []
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    page.screenshot(path=str(ARTIFACTS / f"utilization-shift-{size[0]}.png"), full_page=True)
    assert problems == []
    page.context.close()


@pytest.mark.parametrize("size", WIDTHS, ids=lambda s: f"{s[0]}")
def test_a_week_per_day(browser: Any, shop: UtilShop, size: tuple[int, int]) -> None:
    page, problems = _open(browser, shop, size, "from=2026-01-05&to=2026-01-11&group=day")
    bars = page.locator(".util-bars li").filter(has_text="mill-1")
    # Monday 25 % of its 18 shift hours; the other weekdays ran nothing; Saturday has the
    # end of Friday's night shift, Sunday no shift at all (no percentage)
    labels = bars.locator("svg").get_attribute("aria-label") or ""
    for words in ("Mon 05 25.0 %", "Tue 06 0.0 %", "Sat 10 0.0 %", "Sun 11 –"):
        assert words in labels
    # the week's shift time: Mon 18 h + Tue-Fri 4 × 24 h + Sat 6 h = 120 h; 4.5 h ran
    assert page.locator('[data-util="mill-1"]').inner_text() == "3.8 %"
    ticks = page.locator(".gantt-axis text").all_text_contents()
    assert ticks[:2] == ["Mon 05 Jan", "Tue 06 Jan"]
    assert page.evaluate(OVERFLOW_JS) == []
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    page.screenshot(path=str(ARTIFACTS / f"utilization-week-{size[0]}.png"), full_page=True)
    # the export is the page's table as CSV
    with page.expect_download() as download:
        page.get_by_role("link", name="Export CSV").click()
    text = download.value.path().read_text(encoding="utf-8")
    assert text.startswith("machine,period,shift,start,end,running_h")
    assert "mill-1,2026-01-05,,2026-01-05T00:00:00+01:00" in text
    assert problems == []
    page.context.close()


def test_the_nav_links_to_the_page(browser: Any, shop: UtilShop) -> None:
    page, problems = _open(browser, shop, WIDTHS[0], "from=2026-01-05&to=2026-01-05")
    link = page.get_by_role("navigation", name="Main").get_by_role("link", name="Utilization")
    assert link.get_attribute("aria-current") == "page"
    page.get_by_label("Group by").select_option("week")
    page.get_by_role("button", name="Show").click()
    page.wait_for_url("**group=week**")
    assert "W02 " in (page.locator(".util-bars svg").first.get_attribute("aria-label") or "")
    assert problems == []
    page.context.close()


@pytest.mark.parametrize("size", WIDTHS, ids=lambda s: f"{s[0]}")
def test_the_shift_report_shows_the_early_shift_worked_out_by_hand(
    browser: Any, shop: UtilShop, size: tuple[int, int]
) -> None:
    page, problems = _open(browser, shop, size, "day=2026-01-05&shift=early", "/reports/shift")
    assert page.locator("h1").inner_text() == "Shift report: early of Mon 05 Jan 2026"
    # the early shift is 06:00-14:00 (8 h): mill-1 ran 4.5 h of it, vf2 4 h in 12 cycles
    assert page.locator('[data-util="mill-1"]').inner_text() == "56.3 %"
    assert page.locator('[data-util="vf2-long-name-1"]').inner_text() == "50.0 %"
    assert page.locator('[data-util="lathe-3"]').inner_text() == "0.0 %"
    assert page.locator('[data-parts="vf2-long-name-1"]').inner_text().startswith("12 / ")
    mill = page.locator("#shift-machines tr").filter(has_text="mill-1").inner_text()
    assert mill.split("\t")[-2:] == ["4:30", "8:00"], mill  # running, shift time
    # the alarm at 09:30 lasted half an hour, once
    alarms = page.locator("#shift-alarms tr").filter(has_text="1010 SPINDLE OVERLOAD")
    assert alarms.inner_text().split("\t")[-2:] == ["1", "0:30"], alarms.inner_text()
    # mill-1's stops of 5 minutes or more: an hour from 06:00, from 09:00 (ready, then the
    # alarm: the worst state names it) and from 13:00 (the hour up to the shift's end of a stop
    # that went on and went offline at 14:00: the stop's worst state), half an hour from 12:00
    # (the feed hold); none has a reason
    rows = page.locator("#shift-stops tbody tr").filter(has_text="mill-1").all_inner_texts()
    assert sorted(tuple(r.split("\t")[1:4]) for r in rows) == [
        ("2026-01-05 06:00 CET", "1:00", "ready"),
        ("2026-01-05 09:00 CET", "1:00", "alarm · 1010 SPINDLE OVERLOAD"),
        ("2026-01-05 12:00 CET", "0:30", "stopped"),
        ("2026-01-05 13:00 CET", "1:00", "offline"),
    ], rows
    assert page.evaluate(OVERFLOW_JS) == []
    names = "#shift-machines th[scope=row], #shift-stops td.machine, #shift-alarms td.machine"
    assert page.evaluate(WRAPS_JS, f"{names}, #shift-stops td.nowrap, #shift-stops td.num") == []
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    page.screenshot(path=str(ARTIFACTS / f"shift-report-{size[0]}.png"), full_page=True)
    assert problems == []
    page.context.close()
