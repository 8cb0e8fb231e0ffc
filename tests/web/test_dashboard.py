"""The dashboard in a real browser: Playwright driving Debian's Chromium against a server
process and a virtual shop (two TNCs, a Haas NGC and a Haas on a virtual RS-232 cable).

One shop serves every test of the module (the machine is small and shared). Every page load is
watched: a console error or a request to anywhere but the server fails the test. Screenshots
go to ``tests/artifacts/screenshots`` (gitignored) for a person to look at.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.peers import require_module

require_module("jinja2")
require_module("pygments")
require_module("playwright.sync_api")

from opendnc.lsv2.constants import ExecutionMode  # noqa: E402
from opendnc.server.access import auth  # noqa: E402
from opendnc.server.library import versions as library  # noqa: E402
from opendnc.server.store.db import make_engine, make_sessions, migrate  # noqa: E402
from opendnc.server.store.models import Role  # noqa: E402
from opendnc.sim.fleet import server_config  # noqa: E402
from tests.server.harness import Procs, serve  # noqa: E402
from tests.server.test_from_the_control import FleetThread  # noqa: E402
from tests.web.browser import (  # noqa: E402
    ARTIFACTS,
    PASSWORDS,
    TIMEOUT_MS,
    Shop,
    chromium,
    sync_api,
)

# A released program large enough that its transfer, on a link that answers each telegram
# 40 ms late, spans several card updates (390 kB: a larger one only costs the browser more
# listing to draw).
BIG_LINES = 15_000
BIG = (
    b"%\r\nO03000 (LONG CONTOUR)\r\nG20\r\n"
    + b"".join(
        f"G01 X{i % 97 / 10:.4f} Y{i % 89 / 10:.4f} F40.\r\n".encode() for i in range(BIG_LINES)
    )
    + b"M30\r\n%\r\n"
)
RELEASED_1234 = (
    b"%\r\nO01234 (BRACKET)\r\nG20\r\nG00 G90 G54 X0. Y0.\r\nG01 X1.5 F20.\r\nM30\r\n%\r\n"
)
PUNCHED_1234 = "%\nO01234 (BRACKET OP2)\nG20\nG00 G90 G54 X0. Y0.\nG01 X2.5 F15.\nM30\n%\n"


def _prepare(db_url: str) -> None:
    engine = make_engine(db_url)
    migrate(engine)
    with make_sessions(engine).begin() as session:
        auth.create_user(session, "admin", Role.ADMIN, password=PASSWORDS["admin"])
        auth.create_user(session, "viewer", Role.VIEWER, password=PASSWORDS["viewer"])
        for name, data in (("O03000.nc", BIG), ("O01234.nc", RELEASED_1234)):
            library.add_version(session, name, data, author="test")
            library.release(session, name, 1, actor="test")
        library.add_version(
            session, "O01234.nc", RELEASED_1234.replace(b"X1.5", b"X1.6"), author="t"
        )
    engine.dispose()


@pytest.fixture(scope="module")
def shop(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Shop]:
    tmp = tmp_path_factory.mktemp("dashboard")
    fleet = FleetThread(tmp / "machines", tnc=2, haas=1, serial_haas=1)
    logs = tmp / "logs"
    logs.mkdir()
    procs = Procs(logs)
    try:
        config = tmp / "shop.toml"
        text = server_config(fleet.fleet, poll_interval=0.3, library=tmp / "lib", check="warn")
        config.write_text(text)
        db_url = f"sqlite:///{tmp / 'opendnc.db'}"
        _prepare(db_url)
        base = serve(procs, config, db_url)
        with chromium() as browser:
            yield Shop(base, fleet, procs, browser)
    finally:
        procs.stop_all()
        fleet.stop()


@pytest.fixture
def clean(shop: Shop) -> Iterator[Shop]:
    """The shop, failing the test on any console error or foreign request it caused."""
    shop.problems.clear()
    yield shop
    assert shop.problems == [], shop.problems


def _card(page: Any, name: str) -> Any:
    return page.locator(f"#card-{name} .card-body")


def _wait_all_online(page: Any, names: list[str]) -> None:
    for name in names:
        sync_api.expect(_card(page, name)).not_to_have_attribute(
            "data-state", "offline", timeout=TIMEOUT_MS
        )


def test_log_in_and_every_machine_is_online(clean: Shop) -> None:
    ctx = clean.context()
    page = clean.page(ctx)
    page.goto(clean.url + "/library")
    assert "/login" in page.url  # no session: the login, then back where we were heading
    page.get_by_label("User name").fill("admin")
    page.get_by_label("Password").fill("not-the-password")
    page.get_by_role("button", name="Log in").click()
    sync_api.expect(page.locator("#login-error")).to_contain_text("wrong user name or password")
    # The refusal is a 401, which the browser reports; the only console error allowed here.
    assert clean.problems == [
        "console error: Failed to load resource: the server responded with a status of 401 "
        "(Unauthorized)"
    ]
    clean.problems.clear()
    page.get_by_label("Password").fill(PASSWORDS["admin"])
    page.get_by_role("button", name="Log in").click()
    page.wait_for_url(clean.url + "/library")
    page.get_by_role("link", name="Shop").click()
    names = [m.name for m in clean.fleet.fleet.machines]
    assert sorted(names) == ["haas-1", "haas-serial-1", "tnc-1", "tnc-2"]
    _wait_all_online(page, names)
    for name in names:
        sync_api.expect(_card(page, name).locator(".pill")).not_to_contain_text("offline")
    ctx.close()


def test_send_a_released_program_and_watch_it_go(clean: Shop) -> None:
    overview = clean.login("admin")
    _wait_all_online(overview, ["tnc-1"])
    # Record every progress value the live card shows (the page is never reloaded).
    overview.evaluate(
        """() => {
        window.seen = [];
        window.marker = 'not reloaded';
        const card = document.querySelector('#card-tnc-1');
        new MutationObserver(() => {
            const bar = card.querySelector('progress');
            if (bar) window.seen.push(bar.getAttribute('value'));
        }).observe(card, {childList: true, subtree: true});
    }"""
    )
    # A link slow enough for the transfer to span several card updates (40 ms a telegram).
    tnc = clean.fleet.fleet._tncs[0]
    clean.fleet.call(lambda: setattr(tnc, "latency", 0.04))
    sender = clean.page(overview.context)
    sender.goto(clean.url + "/library/O03000.nc")
    sender.get_by_label("tnc-1").check()
    sender.get_by_role("button", name="Send", exact=True).click()
    sync_api.expect(sender.locator("#send-result")).to_contain_text("tnc-1")

    sync_api.expect(_card(overview, "tnc-1").locator("progress")).to_be_visible()
    sync_api.expect(_card(overview, "tnc-1").locator("progress")).to_have_count(0, timeout=120_000)
    clean.fleet.call(lambda: setattr(tnc, "latency", 0.0))
    seen = overview.evaluate("window.seen")
    assert overview.evaluate("window.marker") == "not reloaded"
    values = [int(v) for v in seen if v is not None]
    assert values, seen
    assert all(0 <= v <= 100 for v in values)

    # The program is on the control, byte for byte, and in the machine's history.
    tnc_root = next(m.root for m in clean.fleet.fleet.machines if m.name == "tnc-1")
    stored = [p for p in tnc_root.rglob("*") if p.name.upper() == "O03000.NC"]
    assert len(stored) == 1
    assert stored[0].read_bytes() == BIG
    overview.get_by_role("link", name="tnc-1").click()
    history = overview.locator("#history")
    sync_api.expect(history.locator("tr", has_text="O03000.nc")).to_contain_text("done")
    # ... and in the machine's file browser, from where it downloads byte for byte.
    files = overview.locator("table.files")
    sync_api.expect(files.locator("tr", has_text="O03000.nc")).to_contain_text("390.0 kB")
    with overview.expect_download() as download:
        overview.get_by_role("link", name="Download O03000.nc").click()
    assert Path(download.value.path()).read_bytes() == BIG
    overview.get_by_role("link", name="History").click()
    overview.get_by_label("Machine").select_option("tnc-1")
    overview.get_by_label("Action").fill("job.send")
    overview.get_by_role("button", name="Filter").click()
    row = overview.locator("table.audit tbody tr").first
    sync_api.expect(row).to_contain_text("O03000.nc")
    sync_api.expect(row).to_contain_text("admin")
    sync_api.expect(row).to_contain_text("ok")
    with overview.expect_download() as download:
        overview.get_by_role("link", name="Export CSV").click()
    csv_text = Path(download.value.path()).read_text()
    assert csv_text.startswith("id,at,actor,action,machine,program")
    assert "job.send" in csv_text
    assert "O03000.nc" in csv_text
    # Delete it through the browser, after the confirmation.
    overview.goto(clean.url + "/machines/tnc-1")
    overview.once("dialog", lambda d: d.accept())
    overview.get_by_role("button", name="Delete O03000.nc").click()
    sync_api.expect(overview.locator("table.files tr", has_text="O03000.nc")).to_have_count(0)
    assert not stored[0].exists()
    overview.context.close()


def test_a_haas_punch_shows_in_the_inbox_with_its_diff(clean: Shop) -> None:
    page = clean.login("admin")
    page.get_by_role("link", name="Inbox").click()
    sync_api.expect(page.get_by_text("Nothing new in the inbox.")).to_be_visible()
    page.evaluate("window.marker = 'not reloaded'")
    sim = clean.fleet.fleet.sims["haas-serial-1"]
    clean.fleet.call(lambda: sim.control.save_program(PUNCHED_1234))
    clean.fleet.fleet.serial_ports["haas-serial-1"].select("punch:O1234")  # operator's key
    # The open inbox shows the reception by itself (the list is live).
    link = page.get_by_role("link", name="O01234.nc")
    sync_api.expect(link).to_be_visible(timeout=60_000)
    assert page.evaluate("window.marker") == "not reloaded"
    sync_api.expect(page.locator("table.inbox tbody tr")).to_contain_text("haas-serial-1")
    link.click()
    diff = page.locator("table.diff")
    sync_api.expect(diff).to_contain_text("v1 (released)")
    changed = diff.locator("tr.replace")
    sync_api.expect(changed.first).to_be_visible()
    # the changed lines side by side, the changed words inside them marked
    title = diff.locator("tr.replace", has_text="O01234 (BRACKET)")
    sync_api.expect(title.locator("td.old")).to_have_text("O01234 (BRACKET)")
    sync_api.expect(title.locator("td.new")).to_have_text("O01234 (BRACKET OP2)")
    sync_api.expect(title.locator("td.new .wd-ins")).to_have_text("(BRACKET OP2)")
    move = diff.locator("tr.replace", has_text="X1.5")
    sync_api.expect(move.locator("td.old .wd-del")).to_have_text(["X1.5", "F20."])
    sync_api.expect(move.locator("td.new .wd-ins")).to_have_text(["X2.5", "F15."])
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    page.screenshot(path=ARTIFACTS / "inbox-diff-1280.png", full_page=True)
    page.set_viewport_size({"width": 768, "height": 1024})
    page.screenshot(path=ARTIFACTS / "inbox-diff-768.png", full_page=True)
    page.get_by_role("button", name="Accept as a new version").click()
    page.wait_for_url("**/library/O01234.nc?v=3")
    sync_api.expect(page.locator("tr.current")).to_contain_text("draft")
    page.context.close()


def test_the_library_list_shows_an_upload_from_elsewhere_without_a_reload(clean: Shop) -> None:
    watcher = clean.login("viewer")
    watcher.goto(clean.url + "/library")
    sync_api.expect(watcher.get_by_role("link", name="O01234.nc")).to_be_visible()
    watcher.evaluate("window.marker = 'not reloaded'")
    uploader = clean.login("admin")
    uploader.goto(clean.url + "/library")
    uploader.get_by_label("File", exact=True).set_input_files(
        {"name": "O07777.nc", "mimeType": "text/plain", "buffer": b"%\nO07777 (LIVE)\nM30\n%\n"}
    )
    uploader.get_by_role("button", name="Upload as a draft").click()
    uploader.wait_for_url("**/library/O07777.nc?v=1")
    row = watcher.locator("table.programs tr", has_text="O07777.nc")
    sync_api.expect(row).to_contain_text("draft")
    assert watcher.evaluate("window.marker") == "not reloaded"
    uploader.context.close()
    watcher.context.close()


def test_a_viewer_is_offered_no_send_and_a_forged_send_is_refused(clean: Shop) -> None:
    page = clean.login("viewer")
    page.goto(clean.url + "/library/O01234.nc")
    sync_api.expect(page.get_by_role("heading", name="O01234.nc")).to_be_visible()
    assert page.get_by_role("button", name="Send").count() == 0
    assert page.get_by_role("button", name="Release v2").count() == 0
    assert page.get_by_role("button", name="Lock").count() == 0
    page.goto(clean.url + "/library")
    assert page.get_by_role("button", name="Upload as a draft").count() == 0
    token = page.evaluate("JSON.parse(document.body.getAttribute('hx-headers'))['X-CSRF-Token']")
    form = {"machines": "tnc-2"}
    # With the viewer's own session and token: the role is refused.
    forged = page.request.post(
        clean.url + "/library/O01234.nc/send", form=form, headers={"X-CSRF-Token": token}
    )
    assert forged.status == 403, forged.text()
    assert "needs operator" in forged.text()
    page.context.close()

    # An admin's session without the page's token (what another site's form would send).
    admin = clean.login("admin")
    csrf_less = admin.request.post(clean.url + "/library/O01234.nc/send", form=form)
    assert csrf_less.status == 403, csrf_less.text()
    assert "CSRF" in csrf_less.text()
    admin.goto(clean.url + "/machines/tnc-2")
    assert admin.locator("#history tr", has_text="O01234.nc").count() == 0  # nothing was queued
    admin.context.close()


def test_a_live_card_follows_the_machine_without_a_reload(clean: Shop) -> None:
    page = clean.login("admin")
    card = _card(page, "tnc-2")
    sync_api.expect(card.locator(".mode")).to_have_text("manual")
    page.evaluate("window.marker = 'not reloaded'")
    tnc = clean.fleet.fleet._tncs[1]
    clean.fleet.call(lambda: setattr(tnc.control.machine, "exec_mode", ExecutionMode.AUTOMATIC))
    try:
        sync_api.expect(card.locator(".mode")).to_have_text("automatic")
    finally:
        clean.fleet.call(lambda: setattr(tnc.control.machine, "exec_mode", ExecutionMode.MANUAL))
    sync_api.expect(card.locator(".mode")).to_have_text("manual")
    # The machine page's status timeline holds both stretches.
    timeline = clean.page(page.context)
    timeline.goto(clean.url + "/machines/tnc-2")
    strip = timeline.get_by_role("img", name="Status of tnc-2")
    sync_api.expect(strip).to_have_attribute("aria-label", re.compile("ready, automatic"))
    label = strip.get_attribute("aria-label") or ""
    assert label.index("ready, manual") < label.index("ready, automatic") < label.rindex("manual")
    timeline.close()
    # The filter shows idle machines only when asked.
    page.get_by_text("Offline", exact=True).click()
    sync_api.expect(page.locator("#card-tnc-2")).to_be_hidden()
    sync_api.expect(page.locator(".empty")).to_be_visible()
    page.get_by_text("All", exact=True).click()
    sync_api.expect(page.locator("#card-tnc-2")).to_be_visible()
    assert page.evaluate("window.marker") == "not reloaded"
    page.context.close()


@pytest.mark.parametrize("viewport", [(1280, 800), (768, 1024)], ids=["1280x800", "768"])
def test_screenshots(clean: Shop, viewport: tuple[int, int]) -> None:
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    tag = f"{viewport[0]}"
    page = clean.login("admin", viewport)
    _wait_all_online(page, ["tnc-1", "tnc-2", "haas-1", "haas-serial-1"])
    page.screenshot(path=ARTIFACTS / f"overview-{tag}.png", full_page=True)
    page.goto(clean.url + "/machines/tnc-1")
    page.screenshot(path=ARTIFACTS / f"machine-{tag}.png", full_page=True)
    page.goto(clean.url + "/library/O01234.nc?a=1&b=2")
    sync_api.expect(page.locator("table.diff tr.replace").first).to_be_visible()
    page.screenshot(path=ARTIFACTS / f"library-diff-{tag}.png", full_page=True)
    page.goto(clean.url + "/inbox?state=all")
    page.screenshot(path=ARTIFACTS / f"inbox-{tag}.png", full_page=True)
    # The send form is reachable with the keyboard alone.
    page.goto(clean.url + "/library/O01234.nc")
    for _ in range(80):
        page.keyboard.press("Tab")
        if page.evaluate("document.activeElement.id") == "send-button":
            break
    else:
        raise AssertionError("Tab never reached the Send button")
    # Every control on these pages has a name.
    for url in ("/", "/machines/tnc-1", "/library/O01234.nc?a=1&b=2", "/inbox", "/history"):
        page.goto(clean.url + url)
        unnamed = page.evaluate(
            """() => [...document.querySelectorAll('a, button, input, select')]
                .filter(e => e.type !== 'hidden')
                .filter(e => !(e.labels && e.labels.length) && !e.getAttribute('aria-label')
                             && !e.textContent.trim() && !e.getAttribute('title'))
                .map(e => e.outerHTML)"""
        )
        assert unnamed == [], (url, unnamed)
    page.context.close()


def test_the_server_log_has_no_tracebacks(shop: Shop) -> None:
    assert "Traceback" not in shop.procs.log("server"), shop.procs.log("server")[-3000:]
