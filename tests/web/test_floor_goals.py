"""The supervisor's glance in Debian's Chromium at 1280 and 768 wide: the overview's cards
show the shift's parts against the ``[goals]`` goal and today so far, the wall display the
shift's parts; the stop-reasons tablet page has large buttons an operator presses (audited,
refused to a viewer); /standards lists each program's standard time seeded by the check's
estimate and an approver sets one (audited, refused to an operator). Nothing is wider than
the window. Screenshots go to /tmp/shots-floor for a person to look at.

The shop's machines point at a port nobody listens on; their last hours are samples written
here, relative to now, so "today" and "this shift" have something to show at any hour."""

from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from typing import Any

import pytest
from sqlalchemy import select

from tests.peers import require_module

require_module("playwright.sync_api")

from playwright import sync_api  # noqa: E402

from opendnc.server.access import auth  # noqa: E402
from opendnc.server.app import build  # noqa: E402
from opendnc.server.config.shop import parse_config  # noqa: E402
from opendnc.server.library import versions  # noqa: E402
from opendnc.server.store.models import AuditEntry, Role, StatusSample, VersionCheck  # noqa: E402
from tests.server.serving import serving  # noqa: E402
from tests.web.browser import ARTIFACTS, chromium, watched_context, watched_page  # noqa: E402

SHOTS = ARTIFACTS  # beside the other pages' screenshots, named floor-goals-*
WIDTHS = [(1280, 800), (768, 1024)]
PASSWORDS = {"boss": "boss-secret-1", "op": "op-secret-1", "viewer": "viewer-secret-1"}
ESTIMATE = 95.0  # seconds: the check's estimate of O1000 stored below
LONG = "FIXTURE-PLATE-OP10-ROUGHING-AND-FINISHING-OF-BOTH-POCKETS-REV-C.nc"

CONFIG = """
[server]
bind = "127.0.0.1:0"
timezone = "Europe/Berlin"

[library]
path = "lib"

[[shifts]]
name = "early"
days = ["mon-sun"]
start = "06:00"
end = "14:00"

[[shifts]]
name = "late"
days = ["mon-sun"]
start = "14:00"
end = "22:00"

[[shifts]]
name = "night"
days = ["mon-sun"]
start = "22:00"
end = "06:00"

[goals]
"mill-1" = { shift = 40 }
"vf2" = { day = 120 }

[[machines]]
name = "mill-1"
kind = "lsv2"
host = "127.0.0.1"
port = 1

[[machines]]
name = "vf2"
kind = "haas_ngc"
host = "127.0.0.1"
mdc_port = 1
"""

OVERFLOW_JS = """() => document.documentElement.scrollWidth - window.innerWidth"""


@dataclass
class Served:
    url: str
    server: Any
    stop_start: datetime  # mill-1's stop that asks for a reason


def _sample(machine: str, at: datetime, state: str, count: int | None = None) -> StatusSample:
    execution = {"running": "ACTIVE", "ready": "READY", "stopped": "FEED_HOLD"}.get(state, "")
    return StatusSample(
        machine=machine,
        at=at,
        state=state,
        mode="AUTOMATIC",
        execution=execution,
        program="O1000.nc",
        part_count=count,
        alarm="1010 SPINDLE OVERLOAD" if state == "alarm" else "",
    )


def _timeline(now: datetime) -> tuple[list[StatusSample], datetime]:
    """The last two hours: mill-1 cycles of 10 min with 2 min between, then a stop of 40
    minutes still going; vf2 cycles of 4 min every 5 counted by its part counter, with a
    15 min alarm."""
    start = now - timedelta(hours=2)
    rows: list[StatusSample] = []
    at = start
    while at < now - timedelta(minutes=40):
        rows.append(_sample("mill-1", at, "running"))
        rows.append(_sample("mill-1", at + timedelta(minutes=10), "ready"))
        at += timedelta(minutes=12)
    stop = now - timedelta(minutes=40)
    rows.append(_sample("mill-1", stop, "stopped"))
    count = 10
    at = start
    while at < now - timedelta(minutes=5):
        if start + timedelta(minutes=50) <= at < start + timedelta(minutes=65):
            rows.append(_sample("vf2", at, "alarm"))
        else:
            rows.append(_sample("vf2", at, "running", count))
            count += 1
            rows.append(_sample("vf2", at + timedelta(minutes=4), "ready", count))
        at += timedelta(minutes=5)
    return rows, stop


@pytest.fixture(scope="module")
def shop(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Served]:
    folder = tmp_path_factory.mktemp("floor-goals")
    server = build(parse_config(CONFIG, base=folder), database=f"sqlite:///{folder / 'db.sqlite'}")
    now = datetime.now(UTC).replace(microsecond=0)
    rows, stop = _timeline(now)
    with server.sessions.begin() as session:
        auth.create_user(session, "boss", Role.APPROVER, password=PASSWORDS["boss"])
        auth.create_user(session, "op", Role.OPERATOR, password=PASSWORDS["op"])
        auth.create_user(session, "viewer", Role.VIEWER, password=PASSWORDS["viewer"])
        session.add_all(rows)
        version, _ = versions.add_version(
            session, "O1000.nc", b"%\nO1000 (POCKET)\nG0 X0 Y0\nM30\n%\n", author="boss"
        )
        # a long name: the table wraps it rather than widen the page at 768
        versions.add_version(session, LONG, b"%\nO2000\nM30\n%\n", author="boss")
        session.flush()
        session.add(VersionCheck(version_id=version.id, limits="", control="fanuc",
                                 facts={"cycle_time_s": ESTIMATE}))  # fmt: skip
    SHOTS.mkdir(parents=True, exist_ok=True)
    with serving(server) as url:
        yield Served(url, server, stop)


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    with chromium() as b:
        yield b


def _login(
    browser: Any, shop: Served, user: str, size: tuple[int, int], path: str
) -> tuple[Any, list[str]]:
    problems: list[str] = []
    page = watched_page(watched_context(browser, shop.url, problems, size), problems)
    page.goto(shop.url + path)
    page.get_by_label("User name").fill(user)
    page.get_by_label("Password").fill(PASSWORDS[user])
    page.get_by_role("button", name="Log in").click()
    page.wait_for_url(shop.url + path)
    return page, problems


def _audit(shop: Served, action: str) -> list[AuditEntry]:
    with shop.server.sessions() as session:
        return list(session.scalars(select(AuditEntry).where(AuditEntry.action == action)))


@pytest.mark.parametrize("size", WIDTHS, ids=lambda s: f"{s[0]}")
def test_the_overview_and_the_wall_show_the_shifts_parts_against_the_goal(
    browser: Any, shop: Served, size: tuple[int, int]
) -> None:
    page, problems = _login(browser, shop, "viewer", size, "/")
    mill = page.locator("#glance-mill-1")
    sync_api.expect(mill.locator("[data-shift-parts]")).to_contain_text("of 40 parts")
    sync_api.expect(mill.locator("[data-expected]")).to_contain_text("expected by now")
    sync_api.expect(mill.locator(".glance-today")).to_contain_text("Utilization")
    sync_api.expect(page.locator("#glance-vf2 [data-shift-parts]")).to_contain_text("parts")
    page.screenshot(path=str(SHOTS / f"floor-goals-overview-{size[0]}.png"), full_page=True)
    assert page.evaluate(OVERFLOW_JS) <= 0
    # a live card's change keeps the glance (the stream swaps the card's live part only)
    page.evaluate("""() => document.dispatchEvent(new CustomEvent('htmx:sseBeforeMessage',
        {detail: {type: 'cards', data: document.querySelector('#card-mill-1').outerHTML
                   .replace(/<div class="glance"[\\s\\S]*$/, '</li>')}}))""")
    sync_api.expect(mill).to_have_count(1)
    page.goto(shop.url + "/wall")
    sync_api.expect(page.locator("#glance-mill-1 [data-shift-parts]")).to_contain_text(
        "of 40 parts"
    )
    sync_api.expect(page.locator("#glance-mill-1 .glance-today")).to_be_hidden()
    page.screenshot(path=str(SHOTS / f"floor-goals-wall-{size[0]}.png"))
    # the glances are read again by themselves
    again = page.request.get(shop.url + "/floor/glances")
    assert again.ok
    assert 'id="glance-vf2" hx-swap-oob="outerHTML"' in again.text()
    assert problems == []


@pytest.mark.parametrize("size", WIDTHS, ids=lambda s: f"{s[0]}")
def test_an_operator_gives_a_stop_its_reason_on_the_tablet_page(
    browser: Any, shop: Served, size: tuple[int, int]
) -> None:
    path = "/floor/reasons/mill-1"
    page, problems = _login(browser, shop, "op", size, path)
    stop = page.locator(f'[data-stop="{shop.stop_start.isoformat()}"]')
    sync_api.expect(stop.locator(".no-reason, [data-reason]")).to_have_count(1)
    button = stop.get_by_role("button", name="material")
    box = button.bounding_box()
    assert box is not None
    assert box["height"] >= 56
    page.screenshot(path=str(SHOTS / f"floor-goals-reasons-{size[0]}.png"), full_page=True)
    assert page.evaluate(OVERFLOW_JS) <= 0
    button.click()
    sync_api.expect(page.get_by_role("status")).to_contain_text("“material” recorded")
    stop = page.locator(f'[data-stop="{shop.stop_start.isoformat()}"]')
    sync_api.expect(stop.locator("[data-reason]")).to_have_text("material")
    sync_api.expect(stop.get_by_role("button", name="material")).to_have_attribute(
        "aria-pressed", "true"
    )
    rows = [a for a in _audit(shop, "downtime.reason") if a.actor == "op"]
    assert rows
    assert rows[-1].detail["reason"] == "material"
    assert problems == []


def test_a_viewer_sees_the_reasons_without_buttons_and_cannot_post_one(
    browser: Any, shop: Served
) -> None:
    page, _problems = _login(browser, shop, "viewer", (768, 1024), "/floor/reasons/mill-1")
    sync_api.expect(page.locator(".reason-stop").first).to_be_visible()
    assert page.locator(".reason-button").count() == 0
    csrf = page.evaluate("() => document.querySelector('input[name=csrf]').value")
    answer = page.request.post(
        shop.url + "/floor/reasons/mill-1",
        form={"csrf": csrf, "start": shop.stop_start.isoformat(), "reason": "setup"},
    )
    assert answer.status == 403


@pytest.mark.parametrize("size", WIDTHS, ids=lambda s: f"{s[0]}")
def test_an_approver_sets_a_standard_time_seeded_by_the_estimate(
    browser: Any, shop: Served, size: tuple[int, int]
) -> None:
    page, problems = _login(browser, shop, "boss", size, "/standards")
    row = page.locator('tr[data-program="O1000.nc"]')
    field = row.get_by_label("Standard seconds of O1000.nc")
    if size[0] == 1280:  # the first visit: the estimate seeds it (1:35.0 = 95 s)
        sync_api.expect(row.locator("[data-standard]")).to_have_text("1:35.0")
        sync_api.expect(field).to_have_value(f"{ESTIMATE:.1f}")
        sync_api.expect(row).to_contain_text("the check's estimate")
    sync_api.expect(page.locator(f'tr[data-program="{LONG}"]')).to_contain_text("none")
    page.screenshot(path=str(SHOTS / f"floor-goals-standards-{size[0]}-before.png"), full_page=True)
    assert page.evaluate(OVERFLOW_JS) <= 0
    seconds = "80" if size[0] == 1280 else "75.5"
    field.fill(seconds)
    row.get_by_role("button", name="Set").click()
    sync_api.expect(page.get_by_role("status")).to_contain_text("O1000.nc v1: standard")
    row = page.locator('tr[data-program="O1000.nc"]')
    sync_api.expect(row.locator("[data-standard]")).to_have_text(
        "1:20.0" if seconds == "80" else "1:15.5"
    )
    sync_api.expect(row).to_contain_text(re.compile(r"set by boss .*estimate 1:35.0"))
    assert page.evaluate(OVERFLOW_JS) <= 0
    page.screenshot(path=str(SHOTS / f"floor-goals-standards-{size[0]}.png"), full_page=True)
    audited = [a.detail["seconds"] for a in _audit(shop, "standard.set")]
    assert float(seconds) in audited
    assert problems == []


def test_standards_are_an_approvers(browser: Any, shop: Served) -> None:
    page, _problems = _login(browser, shop, "op", (1280, 800), "/")
    assert page.get_by_role("link", name="Standards").count() == 0
    assert page.request.get(shop.url + "/standards").status == 403
