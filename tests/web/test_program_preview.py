"""The program page's preview and text in Chromium, offline: the toolpath draws (pixels on the
canvas), the views turn the drawing to what a top, front or side view of the part must show,
a click on a move goes to its line, and a 100,000-line program is a short page whose lines are
reached by anchor, by ?line= and by find.

The expected shapes come from the programs (benchmarks/preview_programs.py), worked out by
hand: the Klartext bracket spans X -10..120, Y -10..80 (the approach from X-10 Y-10 and the
120 x 80 stock) and Z -20..100 (the stock's bottom and the last retract).
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest

from tests.peers import require_module

require_module("playwright.sync_api")

from tests.web.browser import ARTIFACTS, TIMEOUT_MS, Shop, chromium, sync_api  # noqa: E402
from tests.web.preview_shop import preview_shop  # noqa: E402

# the canvas read back: the bounding box of what is drawn, and the colours it holds
DRAWN = """(canvas) => {
  window.opendncPreview.draw();  // the drawing buffer is kept only until the frame shows
  const copy = document.createElement('canvas');
  copy.width = canvas.width; copy.height = canvas.height;
  const ctx = copy.getContext('2d');
  ctx.drawImage(canvas, 0, 0);
  const data = ctx.getImageData(0, 0, copy.width, copy.height).data;
  const bg = [0xfb, 0xfc, 0xfe];
  let n = 0, x0 = 1e9, y0 = 1e9, x1 = -1, y1 = -1;
  const colours = {};
  for (let i = 0; i < data.length; i += 4) {
    const d = Math.abs(data[i] - bg[0]) + Math.abs(data[i+1] - bg[1]) + Math.abs(data[i+2] - bg[2]);
    if (d < 40) continue;
    n++;
    const p = i / 4, x = p % copy.width, y = Math.floor(p / copy.width);
    if (x < x0) x0 = x; if (x > x1) x1 = x; if (y < y0) y0 = y; if (y > y1) y1 = y;
    const hex = v => v.toString(16).padStart(2, '0');
    const key = '#' + hex(data[i]) + hex(data[i+1]) + hex(data[i+2]);
    colours[key] = (colours[key] || 0) + 1;
  }
  return {n, x0, y0, x1, y1, w: copy.width, h: copy.height, colours};
}"""


# A 100,000-line program's first page view checks it and draws its preview: a few CPU seconds,
# which a loaded machine stretches past Playwright's 30 s (seen at load 17). Speed is measured
# in benchmarks/preview.py, not here.
LARGE_PAGE_MS = 120_000


@pytest.fixture(scope="module")
def shop(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Shop]:
    with preview_shop(tmp_path_factory.mktemp("preview")) as served, chromium() as browser:
        yield Shop(served.url, None, None, browser)  # type: ignore[arg-type]


@pytest.fixture
def clean(shop: Shop) -> Iterator[Shop]:
    """The shop, failing the test on any console error or foreign request it caused."""
    shop.problems.clear()
    yield shop
    assert shop.problems == [], shop.problems


def _login(shop: Shop, viewport: tuple[int, int] = (1280, 800)) -> Any:
    page = shop.page(shop.context(viewport))
    page.goto(shop.url + "/login")
    page.get_by_label("User name").fill("viewer")
    page.get_by_label("Password").fill("viewer-secret-1")
    page.get_by_role("button", name="Log in").click()
    page.wait_for_url(shop.url + "/")
    return page


def _drawn(page: Any) -> dict[str, Any]:
    page.wait_for_selector(".preview-view[data-drawn]", timeout=TIMEOUT_MS * 4)
    # a frame for a redraw the last input asked for
    page.evaluate("() => new Promise(r => requestAnimationFrame(() => requestAnimationFrame(r)))")
    found: dict[str, Any] = page.locator(".preview-canvas").evaluate(DRAWN)
    return found


def _near(colours: dict[str, int], hex_colour: str, slack: int = 60) -> int:
    """Pixels within ``slack`` (summed over R, G, B) of a colour (lines are antialiased)."""
    want = [int(hex_colour[i : i + 2], 16) for i in (1, 3, 5)]
    total = 0
    for key, count in colours.items():
        got = [int(key[i : i + 2], 16) for i in (1, 3, 5)]
        if sum(abs(a - b) for a, b in zip(got, want, strict=True)) <= slack:
            total += count
    return total


def test_the_preview_draws_and_each_view_shows_its_two_axes(clean: Shop) -> None:
    page = _login(clean)
    page.goto(clean.url + "/library/BRACKET.H")
    iso = _drawn(page)
    assert iso["n"] > 500, iso
    # the cut in the first tool's colour, the rapids in theirs, the stock in grey
    assert _near(iso["colours"], "#1f5fbf") > 50
    assert _near(iso["colours"], "#e8590c") > 20
    assert _near(iso["colours"], "#8a94a6") > 50
    sync_api.expect(page.locator(".preview-facts")).to_contain_text("T7")
    spans = {"top": (130, 90), "front": (130, 120), "side": (90, 120)}  # (across, up)
    for view, (across, up) in spans.items():
        page.get_by_role("button", name=view.capitalize(), exact=True).click()
        sync_api.expect(page.locator(f'[data-view="{view}"]')).to_have_attribute(
            "aria-pressed", "true"
        )
        box = _drawn(page)
        ratio = (box["x1"] - box["x0"]) / (box["y1"] - box["y0"])
        assert ratio == pytest.approx(across / up, rel=0.06), (view, box)
        # the fitted view fills 90 % of the canvas along one of its sides
        fill = max((box["x1"] - box["x0"]) / box["w"], (box["y1"] - box["y0"]) / box["h"])
        assert fill == pytest.approx(0.9, abs=0.03), (view, box)
    # without rapids, none of their colour is left
    page.get_by_label("Rapids").uncheck()
    assert _near(_drawn(page)["colours"], "#e8590c", slack=30) == 0
    page.screenshot(path=ARTIFACTS / "preview-bracket.png", full_page=True)


def test_a_click_on_a_move_goes_to_its_line(clean: Shop) -> None:
    page = _login(clean)
    page.goto(clean.url + "/library/BRACKET.H")
    page.get_by_role("button", name="Top", exact=True).click()
    _drawn(page)
    # the contour's straight edge L X+90 (block 8, file line 9) runs along Y+10 at Z-5:
    # in the top view it is a horizontal line; find one of its pixels and click there
    spot = page.locator(".preview-canvas").evaluate(
        """(canvas) => {
          const p = window.opendncPreview;
          const rect = canvas.getBoundingClientRect();
          const m = p.matrix(rect.width, rect.height);
          const project = (x, y, z) => [
            rect.left + (m[0]*x + m[4]*y + m[8]*z + m[12] + 1) / 2 * rect.width,
            rect.top + (1 - (m[1]*x + m[5]*y + m[9]*z + m[13])) / 2 * rect.height];
          return project(50, 10, -5);
        }"""
    )
    page.mouse.click(spot[0], spot[1])
    page.wait_for_url("**#L9")
    row = page.locator(".listing-box #L9")
    sync_api.expect(row).to_have_class("ln hl")
    sync_api.expect(row).to_contain_text("L X+90")
    sync_api.expect(row).to_be_in_viewport()


def test_a_100000_move_program_draws(clean: Shop) -> None:
    page = _login(clean)
    page.goto(clean.url + "/library/O02000.nc", timeout=LARGE_PAGE_MS)
    drawn = _drawn(page)
    assert drawn["n"] > 5_000, drawn
    for colour in ("#1f5fbf", "#2f9e44", "#8e44ad", "#0c8599"):  # the four tools
        assert _near(drawn["colours"], colour) > 20, colour
    sync_api.expect(page.locator(".preview-facts")).to_contain_text("100,4")  # moves drawn for


def test_a_100000_line_program_is_a_short_page_and_every_line_is_reachable(
    clean: Shop,
) -> None:
    page = _login(clean, (1280, 800))
    page.goto(clean.url + "/library/O04000.nc#L99990", timeout=LARGE_PAGE_MS)
    page.wait_for_selector(".listing.ready")
    height = page.evaluate("() => document.documentElement.scrollHeight")
    assert height < 3_000, height
    row = page.locator(".listing-box #L99990")
    sync_api.expect(row).to_contain_text("(LINE 99990)")
    sync_api.expect(row).to_have_class("ln hl")
    sync_api.expect(row).to_be_in_viewport()
    # go to line: the box scrolls there and the anchor follows
    page.get_by_label("Go to line").fill("12345")
    page.get_by_label("Go to line").press("Enter")
    page.wait_for_url("**#L12345")
    sync_api.expect(page.locator(".listing-box #L12345")).to_be_in_viewport()
    # find: one line holds "(LINE 77777)"
    find = page.get_by_label("Find in text")
    find.fill("LINE 77777)")
    sync_api.expect(page.locator(".listing-count")).to_have_text("1 of 1")
    sync_api.expect(page.locator(".listing-box #L77777 mark.cur")).to_have_text("LINE 77777)")
    sync_api.expect(page.locator(".listing-box #L77777")).to_be_in_viewport()
    # many matches: next goes to the next one
    find.fill("(LINE 5000")
    sync_api.expect(page.locator(".listing-count")).to_contain_text(" of 11")
    before = page.locator(".listing-box mark.cur").evaluate("m => m.closest('.ln').id")
    page.get_by_role("button", name="Next match").click()
    after = page.locator(".listing-box mark.cur").evaluate("m => m.closest('.ln').id")
    assert before != after
    # ?line= from another page (the problem list links the same way)
    page.goto(clean.url + "/library/O04000.nc?line=54321", timeout=LARGE_PAGE_MS)
    page.wait_for_selector(".listing.ready")
    sync_api.expect(page.locator(".listing-box #L54321")).to_be_in_viewport()
    sync_api.expect(page.locator(".listing-box #L54321")).to_have_class("ln hl")
    page.screenshot(path=ARTIFACTS / "listing-100k.png", full_page=True)


def test_a_program_without_moves_says_so(clean: Shop) -> None:
    page = _login(clean)
    page.goto(clean.url + "/library/O05000.nc")
    page.wait_for_selector(".preview-view[data-drawn]")
    sync_api.expect(page.locator(".preview-status")).to_have_text(
        "No move to draw: the program never moves from a known position."
    )
    sync_api.expect(page.locator(".preview-facts")).to_contain_text("no tool change")
