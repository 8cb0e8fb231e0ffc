"""The shop floor in Chromium: filter counts, times on the shop's clock, the alarm alert, the
wall display, and a layout without overflow or names, dates and sizes broken inside a word.

One in-process server for the module (a virtual TNC and two virtual Haas NGCs, the shop in
Europe/Berlin); the alarm is the control's own: a virtual Haas raises one, the server reads
its status word over MDC and the classifier says "alarm".
"""

from __future__ import annotations

import re
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.peers import require_module

require_module("jinja2")
require_module("playwright.sync_api")

from opendnc.server.access import auth  # noqa: E402
from opendnc.server.app import build  # noqa: E402
from opendnc.server.config.shop import parse_config  # noqa: E402
from opendnc.server.library import versions as library  # noqa: E402
from opendnc.server.store.models import Role  # noqa: E402
from opendnc.sim.fleet import server_config  # noqa: E402
from opendnc.sim.haas.machine import Alarm  # noqa: E402
from tests.server.harness import wait_for  # noqa: E402
from tests.server.serving import serving  # noqa: E402
from tests.server.test_from_the_control import FleetThread  # noqa: E402
from tests.web.browser import (  # noqa: E402
    ARTIFACTS,
    PASSWORDS,
    TIMEOUT_MS,
    Shop,
    chromium,
    sync_api,
    watched_context,
    watched_page,
)

PROGRAM = b"%\r\nO01000 (FACE)\r\nG20\r\nG00 X0. Y0.\r\nM30\r\n%\r\n"
WIDTHS = ((1280, 800), (768, 1024))
ALARM = Alarm(1010, "COOLANT LOW")


@pytest.fixture(scope="module")
def shop(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Shop]:
    tmp = tmp_path_factory.mktemp("floor")
    fleet = FleetThread(tmp / "machines", tnc=1, haas=2)
    try:
        # check = "warn": a Haas program goes to the TNCs too (the check has its own tests)
        text = server_config(fleet.fleet, poll_interval=0.3, library=tmp / "lib", check="warn")
        # the shop's clock: every time a person reads is on it, with its zone
        text = text.replace("[server]\n", '[server]\ntimezone = "Europe/Berlin"\n', 1)
        server = build(parse_config(text, base=tmp), database=f"sqlite:///{tmp / 'db.sqlite'}")
        with server.sessions.begin() as session:
            auth.create_user(session, "admin", Role.ADMIN, password=PASSWORDS["admin"])
            library.add_version(session, "O01000.nc", PROGRAM, author="test")
            library.release(session, "O01000.nc", 1, actor="test")
        with serving(server) as url, chromium() as browser:
            yield Shop(url, fleet, None, browser)  # type: ignore[arg-type]
    finally:
        fleet.stop()


@pytest.fixture
def clean(shop: Shop) -> Iterator[Shop]:
    """The shop, failing the test on any console error or foreign request it caused."""
    shop.problems.clear()
    yield shop
    assert shop.problems == [], shop.problems


def _machines(shop: Shop) -> list[str]:
    return [m.name for m in shop.fleet.fleet.machines]


def _settled(page: Any, names: list[str]) -> None:
    # every machine's first reading is on its card (none still offline from the start)
    for name in names:
        sync_api.expect(page.locator(f"#card-{name} .card-body")).not_to_have_attribute(
            "data-state", "offline", timeout=TIMEOUT_MS
        )
        sync_api.expect(page.locator(f"#card-{name} .updated time")).to_have_count(1)


def _counts(page: Any) -> dict[str, int]:
    found: dict[str, str] = page.evaluate(
        """() => Object.fromEntries([...document.querySelectorAll('.filters [data-count]')]
            .map(e => [e.dataset.count, e.textContent.trim()]))"""
    )
    return {k: int(v) for k, v in found.items()}


def test_filters_count_the_cards_and_times_are_on_the_shops_clock(clean: Shop) -> None:
    page = clean.login("admin")
    names = _machines(clean)
    page.goto(clean.url + "/")  # drawn after every machine was read once
    _settled(page, names)
    page.reload()
    states = page.eval_on_selector_all(".card-body", "els => els.map(e => e.dataset.state)")
    counts = _counts(page)
    assert counts["all"] == len(names) == 3
    for state in ("running", "ready", "stopped", "alarm", "offline", "unknown"):
        assert counts[state] == states.count(state), (state, counts, states)
    assert counts["ready"] == 3  # idle virtual controls, polled
    # A filter shows its machines only.
    page.locator("label[for=filter-alarm]").click()
    sync_api.expect(page.locator(".cards > .card:visible")).to_have_count(0)
    sync_api.expect(page.locator(".empty")).to_be_visible()
    page.locator("label[for=filter-ready]").click()
    sync_api.expect(page.locator(".cards > .card:visible")).to_have_count(3)
    # Times read by people are on the shop's clock with its zone (CET or CEST), the ISO
    # instant with its offset in the title.
    sync_api.expect(page.locator("h1")).to_contain_text("times in Europe/Berlin")
    updated = page.locator("#card-tnc-1 .updated time")
    assert re.fullmatch(r"(\d{4}-\d\d-\d\d )?\d\d:\d\d CES?T", updated.inner_text()), (
        updated.inner_text()
    )
    title = updated.get_attribute("title") or ""
    assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:00\+0[12]:00", title), title
    page.context.close()


def _alarm(shop: Shop, machine: str, on: bool) -> None:
    control = shop.fleet.fleet.sims[machine].control
    shop.fleet.call(lambda: control.raise_alarm(ALARM) if on else control.reset())


def test_a_machine_going_into_alarm_is_announced(clean: Shop) -> None:
    page = clean.login("admin")
    _settled(page, _machines(clean))
    banner = page.locator("#alarm-banner")
    sync_api.expect(banner).to_be_hidden()
    # The sound is the person's choice, kept in this browser.
    page.get_by_label("Alarm sound").check()
    page.reload()
    sync_api.expect(page.get_by_label("Alarm sound")).to_be_checked()
    _settled(page, _machines(clean))
    assert page.evaluate("window.opendnc.beeps") == 0
    try:
        _alarm(clean, "haas-1", on=True)
        card = page.locator("#card-haas-1")
        sync_api.expect(card.locator(".card-body")).to_have_attribute("data-state", "alarm")
        sync_api.expect(card).to_have_class(re.compile(r"\balarm-new\b"))  # it flashes
        # what the control says (MDC tells an alarm, not which)
        sync_api.expect(card.locator(".alarm-text")).to_contain_text("ALARM")
        sync_api.expect(banner).to_be_visible()
        sync_api.expect(banner.locator("li")).to_have_text("haas-1: ALARM")
        assert page.evaluate("window.opendnc.beeps") == 1  # one beep for one new alarm
        assert _counts(page)["alarm"] == 1
        # the card's colour is the classifier's alarm red, from the one mapping
        colour = card.locator(".card-body").evaluate("e => getComputedStyle(e).borderTopColor")
        assert colour == "rgb(208, 49, 45)"  # the utilization page's alarm red too
        # Turned off, the next alarm is shown but silent.
        page.get_by_label("Alarm sound").uncheck()
        _alarm(clean, "haas-2", on=True)
        sync_api.expect(page.locator("#card-haas-2 .card-body")).to_have_attribute(
            "data-state", "alarm"
        )
        sync_api.expect(page.locator("#alarm-list li")).to_have_count(2)
        assert page.evaluate("window.opendnc.alerts") == 2
        assert page.evaluate("window.opendnc.beeps") == 1
        ARTIFACTS.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=ARTIFACTS / "floor-alarm-1280.png", full_page=True)
    finally:
        _alarm(clean, "haas-1", on=False)
        _alarm(clean, "haas-2", on=False)
    sync_api.expect(banner).to_be_hidden()
    sync_api.expect(page.locator("#card-haas-1")).not_to_have_class(re.compile(r"alarm-new"))
    assert _counts(page)["alarm"] == 0
    page.context.close()


def test_the_wall_display_is_large_has_no_controls_and_turns_its_pages(clean: Shop) -> None:
    # A screen one row of cards high: the three machines need pages, shown in turn.
    page = clean.login("admin", viewport=(1280, 600))
    page.goto(clean.url + "/wall?every=3")
    sync_api.expect(page.locator(".cards > .card")).to_have_count(3)
    assert page.locator("button, input, select, textarea, nav, form").count() == 0
    # Cards are swapped in as the machines report: find and measure in one script, so the
    # element measured is the one in the page (a detached one has no computed size).
    size, detail = page.evaluate(
        "['.card h2', '.card dd'].map(s =>"
        " parseFloat(getComputedStyle(document.querySelector(s)).fontSize))"
    )
    # on a 55" full-HD screen (0.63 mm a pixel) a name is 30 mm high, its details 18 mm
    assert size >= 48
    assert detail >= 28
    pages = int(page.evaluate("document.body.dataset.wallPages"))
    assert pages >= 2
    visible = page.locator(".cards > .card:visible")
    sync_api.expect(page.locator("#wall-page")).to_have_text(f"page 1 of {pages}")
    sync_api.expect(page.locator("#wall-page")).to_have_text(f"page 2 of {pages}")
    # the page's number and its first card read in one script: on a loaded machine a page
    # can turn between two separate reads
    shown = (
        "() => [document.querySelector('#wall-page').textContent,"
        " [...document.querySelectorAll('.cards > .card')]"
        ".find(c => c.getClientRects().length > 0)?.id]"
    )
    label, first = page.evaluate(shown)
    turned = wait_for(
        "the next page", lambda: (now := page.evaluate(shown))[0] != label and now, timeout=30
    )
    assert turned[1] != first, (label, first, turned)
    # every card on a page is inside the screen
    for box in (c.bounding_box() for c in visible.all()):
        assert box is not None
        assert box["y"] + box["height"] <= 600
    # the shop's zone named as the cards name it (CET, CEST), not the browser's "GMT+1"
    sync_api.expect(page.locator("#wall-clock")).to_have_text(re.compile(r"\d\d:\d\d CES?T"))
    page.context.close()


# Elements whose text is a name, a date or a size: never broken inside a word.
WHOLE = ".card h2 a, .pill, time, td.size, td.when, td.machine a, .nowrap, .count, .native-mode"
# What may scroll its own content (a wide table, a console): not an overflow.
SCROLLERS = ".table-wrap, .console, .machines-pick, pre, .code"

MEASURE = """([whole, scrollers]) => {
  const problems = [];
  const visible = e => e.getClientRects().length > 0 && getComputedStyle(e).visibility !== 'hidden';
  const inScroller = e => e.parentElement && e.parentElement.closest(scrollers);
  for (const e of document.querySelectorAll('main *, header *')) {
    if (!visible(e) || inScroller(e) || e.closest('.sr-only')) continue;
    const style = getComputedStyle(e);
    const clips = style.overflowX === 'hidden' && style.textOverflow === 'ellipsis';
    if (e.scrollWidth > e.clientWidth + 1 && e.clientWidth > 0 && !clips
        && !e.matches(scrollers) && style.display !== 'inline') {
      problems.push('overflows: ' + e.outerHTML.slice(0, 120));
    }
    const box = e.getBoundingClientRect(), parent = e.parentElement.getBoundingClientRect();
    if (e.parentElement !== document.body && box.right > parent.right + 1
        && getComputedStyle(e.parentElement).overflowX === 'visible' && !clips) {
      problems.push('sticks out: ' + e.outerHTML.slice(0, 120));
    }
  }
  if (document.documentElement.scrollWidth > window.innerWidth) {
    problems.push('page scrolls sideways');
  }
  for (const e of document.querySelectorAll(whole)) {
    if (!visible(e) || inScroller(e) && !e.closest('td')) continue;
    const walker = document.createTreeWalker(e, NodeFilter.SHOW_TEXT);
    for (let node = walker.nextNode(); node; node = walker.nextNode()) {
      const re = /\\S+/g;
      let m;
      while ((m = re.exec(node.data))) {
        const range = document.createRange();
        range.setStart(node, m.index);
        range.setEnd(node, m.index + m[0].length);
        const lines = new Set([...range.getClientRects()].map(r => Math.round(r.top)));
        if (lines.size > 1) {
          problems.push('breaks inside "' + m[0] + '" in ' + e.outerHTML.slice(0, 100));
        }
      }
    }
  }
  return problems;
}"""


@pytest.mark.parametrize("viewport", WIDTHS, ids=lambda v: f"{v[0]}")
def test_no_overflow_and_no_word_broken_at_both_widths(clean: Shop, viewport: Any) -> None:
    page = clean.login("admin", viewport=viewport)
    names = _machines(clean)
    _settled(page, names)
    # a finished job on a card and in the histories (its time, its size)
    page.goto(clean.url + "/library/O01000.nc")
    page.get_by_label("tnc-1").check()
    page.get_by_role("button", name="Send", exact=True).click()
    sync_api.expect(page.locator("#send-result")).to_contain_text("tnc-1")
    for path in ("/", "/machines/tnc-1", "/machines/haas-2", "/history", "/wall"):
        page.goto(clean.url + path)
        if path == "/machines/tnc-1":
            sync_api.expect(page.locator("#history")).to_contain_text("O01000.nc")
        problems = page.evaluate(MEASURE, [WHOLE, SCROLLERS])
        ARTIFACTS.mkdir(parents=True, exist_ok=True)
        name = path.strip("/").replace("/", "-") or "floor"
        page.screenshot(path=ARTIFACTS / f"floor-{name}-{viewport[0]}.png", full_page=True)
        assert problems == [], (path, viewport, problems)
    page.context.close()


def test_all_machines_in_one_click_and_a_question_before_sending_to_many(clean: Shop) -> None:
    page = clean.login("admin")
    page.goto(clean.url + "/library/O01000.nc")
    names = _machines(clean)
    every = page.get_by_label(f"All {len(names)} machines")
    every.check()
    for name in names:
        sync_api.expect(page.get_by_label(name, exact=True)).to_be_checked()
    page.get_by_label("haas-2", exact=True).uncheck()
    assert every.evaluate("e => e.indeterminate")  # some, not all
    asked: list[str] = []

    def answer(dialog: Any) -> None:
        asked.append(dialog.message)
        dialog.dismiss()  # the first time: no

    page.once("dialog", answer)
    page.get_by_role("button", name="Send", exact=True).click()
    sync_api.expect(page.locator("#send-result")).to_be_empty()
    assert asked == ["Send to 2 machines (tnc-1, haas-1)?"]
    page.once("dialog", lambda d: (asked.append(d.message), d.accept()))
    page.get_by_role("button", name="Send", exact=True).click()
    sync_api.expect(page.locator("#send-result")).to_contain_text("haas-1")
    sync_api.expect(page.locator("#send-result")).to_contain_text("tnc-1")
    assert len(asked) == 2
    # one machine: no question
    every.check()  # all, then none
    every.uncheck()
    for name in names:
        sync_api.expect(page.get_by_label(name, exact=True)).not_to_be_checked()
    page.get_by_label("haas-2", exact=True).check()
    page.on("dialog", lambda d: (asked.append(d.message), d.dismiss()))
    page.get_by_role("button", name="Send", exact=True).click()
    sync_api.expect(page.locator("#send-result")).to_contain_text("haas-2")
    assert len(asked) == 2
    page.context.close()


def _bare_server(tmp: Path) -> Any:
    """A server without machines on its own SQLite file, that a test may stop and start."""
    text = '[server]\ntimezone = "Europe/Berlin"\n[library]\npath = "lib"\n'
    server = build(parse_config(text, base=tmp), database=f"sqlite:///{tmp / 'db.sqlite'}")
    with server.sessions.begin() as session:
        if auth.find_user(session, "admin") is None:
            auth.create_user(session, "admin", Role.ADMIN, password=PASSWORDS["admin"])
    return server


def test_a_stopped_server_greys_the_page_within_5_s_and_it_comes_back(
    clean: Shop, tmp_path: Path
) -> None:
    """40 s after the server stopped, the page still said "Running, updated just now": a lost
    stream greys the page, says since when, and the page reconnects by itself."""
    problems: list[str] = []
    with serving(_bare_server(tmp_path)) as url:
        port = int(url.rsplit(":", 1)[1])
        page = watched_page(watched_context(clean.browser, url, problems, (1280, 800)), problems)
        page.goto(url + "/")
        page.get_by_label("User name").fill("admin")
        page.get_by_label("Password").fill(PASSWORDS["admin"])
        page.get_by_role("button", name="Log in").click()
        page.wait_for_url(url + "/")
        # the stream is open and its heartbeat heard: live
        page.wait_for_function("window.opendncLive && window.opendncLive.opened > 0")
        banner = page.locator("#stale")
        sync_api.expect(banner).to_be_hidden()
    # the server has stopped (its thread joined); the page knows within 5 s of the stop. Timed
    # from here: the stop itself (up to 2 s for its open streams, more on a loaded machine)
    # left 1.6 s of the 5 once in CI when timed from before it.
    stopped = time.monotonic()
    left = max(0.0, 5.0 - (time.monotonic() - stopped))
    sync_api.expect(banner).to_be_visible(timeout=left * 1000)
    sync_api.expect(banner).to_contain_text(
        re.compile(r"No connection to the server since \d\d:\d\d:\d\d CES?T")
    )
    assert page.evaluate("document.documentElement.classList.contains('stale')")
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    page.screenshot(path=ARTIFACTS / "floor-stale-1280.png")
    # the same server again, on the same port: the page comes back by itself
    with serving(_bare_server(tmp_path), port=port):
        sync_api.expect(banner).to_be_hidden(timeout=TIMEOUT_MS)
        assert not page.evaluate("document.documentElement.classList.contains('stale')")
        page.context.close()
    # what the browser and htmx log while the server is away (a stream cut, refused
    # reconnections); nothing else
    away = ("ERR_CONNECTION_REFUSED", "ERR_INCOMPLETE_CHUNKED_ENCODING", "[object Event]")
    assert [p for p in problems if not any(a in p for a in away)] == [], problems


def test_per_shift_without_shifts_says_why_it_is_empty(clean: Shop) -> None:
    """ "By shift" in a shop without shifts showed empty panels and no word why."""
    page = clean.login("admin")
    page.goto(clean.url + "/utilization?group=shift")
    hint = page.locator("#no-shifts")
    sync_api.expect(hint).to_contain_text("No shifts are configured")
    assert page.locator(".util-bars").count() == 0
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    page.screenshot(path=ARTIFACTS / "floor-utilization-shift-1280.png", full_page=True)
    hint.get_by_role("link", name="per day").click()
    sync_api.expect(page.locator("#bars-h")).to_have_text("Per day")
    page.context.close()
