"""The Net share page and the program page's layout in Debian's Chromium.

One in-process server for the module: a virtual TNC and two virtual Haas NGCs, the shop in
Europe/Berlin, and a hybrid net share whose NAS folder (written here, with a known time) holds
a released program, a draft, a program edited after its release, one the library never saw and
one named in other letter case. The server copies them to both machines' shares; the page
shows each folder, each file's size, time (with the zone) and how it compares with the
library, and the share's audit rows, live, read-only, without overflow at 1280×800 and 768
wide. Without ``[netshare]`` the page says so and how to add one.

The program page: the send panel is a sidebar beside the rest of the page, so no empty
column is left beside it (nor, for a viewer, where it would be). Screenshots go to
``tests/artifacts/screenshots`` for a person to look at.
"""

from __future__ import annotations

import hashlib
import os
import re
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import UTC, datetime
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
from tests.server.harness import wait_for  # noqa: E402
from tests.server.test_from_the_control import FleetThread  # noqa: E402
from tests.web.browser import ARTIFACTS, PASSWORDS, Shop, chromium, sync_api  # noqa: E402
from tests.web.inprocess import serve_one_tnc, serving  # noqa: E402
from tests.web.test_floor import MEASURE, SCROLLERS, WHOLE  # noqa: E402

RELEASED = b"%\r\nO01000 (FACE)\r\nG20\r\nG00 X0. Y0.\r\nM30\r\n%\r\n"
DRAFT = b"%\r\nO02000 (DRILL)\r\nG20\r\nG81 Z-0.5 R0.1 F10.\r\nM30\r\n%\r\n"
SPOT = b"%\r\nO04000 (SPOT)\r\nG20\r\nG81 Z-0.1 R0.1 F8.\r\nM30\r\n%\r\n"
TWIN = b"%\r\nO06000 (DEBURR)\r\nG20\r\nG01 X1. F20.\r\nM30\r\n%\r\n"
# what the CAM office left in the NAS folder, and how each stands beside the library
NAS = {
    "O01000.nc": RELEASED,
    "O02000.nc": DRAFT,
    "O04000.nc": SPOT.replace(b"F8.", b"F12."),
    "O05000.nc": b"%\r\nO05000 (NEW JOB)\r\nG20\r\nM30\r\n%\r\n",
    "o06000.NC": TWIN,  # SMB shares fold case: the library's O06000.nc
}
EXPECTED = {
    "O01000.nc": "same as released v1",
    "O02000.nc": "not released",
    "O04000.nc": "differs from released v1",
    "O05000.nc": "not in library",
    "o06000.NC": "same as released v1",
}
# The NAS files' time: 10:00 UTC on 1 July 2025 is noon in Berlin, on summer time.
WRITTEN = datetime(2025, 7, 1, 10, 0, tzinfo=UTC)
WRITTEN_BERLIN = "2025-07-01 12:00:00 CEST"
WIDTHS = ((1280, 800), (768, 1024))

ROWS_JS = """(key) => [...document.querySelectorAll(
    `section[aria-labelledby="folder-${key}-h"] tbody tr`)].map(r => ({
  name: r.querySelector('td.name').innerText.trim(),
  href: r.querySelector('td.name a') ? r.querySelector('td.name a').getAttribute('href') : null,
  size: r.querySelector('td.size').innerText.trim(),
  bytes: r.querySelector('td.size').getAttribute('title'),
  when: r.querySelector('td.when').innerText.trim(),
  iso: r.querySelector('td.when time').getAttribute('datetime'),
  match: r.querySelector('td.match').innerText.replace(/\\s+/g, ' ').trim(),
}))"""
ACTIVITY_JS = """() => [...document.querySelectorAll('.share-activity tbody tr')]
  .filter(r => r.cells.length > 1).map(r => ({
    what: r.cells[1].innerText.trim(), machine: r.cells[2].innerText.trim(),
    file: r.cells[3].innerText.trim(), result: r.cells[4].innerText.trim()}))"""


@dataclass
class ShareShop:
    """The running shop with its NAS folder and the machines' shares."""

    shop: Shop
    nas: Path
    shares: dict[str, Path]


@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ShareShop]:
    tmp = tmp_path_factory.mktemp("netshare-page")
    nas = tmp / "nas"
    nas.mkdir()
    stamp = WRITTEN.timestamp()
    for name, data in NAS.items():
        (nas / name).write_bytes(data)
        os.utime(nas / name, (stamp, stamp))
    fleet = FleetThread(tmp / "machines", tnc=1, haas=2)
    try:
        text = server_config(
            fleet.fleet,
            poll_interval=0.3,
            library=tmp / "lib",
            check="warn",
            timezone="Europe/Berlin",
            netshare=nas,
            netshare_interval=0.2,
        )
        server = build(parse_config(text, base=tmp), database=f"sqlite:///{tmp / 'db.sqlite'}")
        with server.sessions.begin() as session:
            for user, role in (("admin", Role.ADMIN), ("viewer", Role.VIEWER)):
                auth.create_user(session, user, role, password=PASSWORDS[user])
            for name, data in (
                ("O01000.nc", RELEASED),
                ("O02000.nc", DRAFT),
                ("O04000.nc", SPOT),
                ("O06000.nc", TWIN),
            ):
                library.add_version(session, name, data, author="test")
                if data is not DRAFT:
                    library.release(session, name, 1, actor="test")
        shares = {m.name: m.root for m in fleet.fleet.machines if m.kind == "haas_ngc"}
        with serving(server) as url, chromium() as browser:
            # the server copies every NAS file into both shares (what the page then shows)
            wait_for(
                "the net share's copies",
                lambda: all(
                    (share / name).is_file() and (share / name).read_bytes() == data
                    for share in shares.values()
                    for name, data in NAS.items()
                ),
            )
            yield ShareShop(Shop(url, fleet, None, browser), nas, shares)  # type: ignore[arg-type]
    finally:
        fleet.stop()


@pytest.fixture
def clean(served: ShareShop) -> Iterator[ShareShop]:
    """The shop, failing the test on any console error or foreign request it caused."""
    served.shop.problems.clear()
    yield served
    assert served.shop.problems == [], served.shop.problems


def _shoot(page: Any, name: str) -> None:
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    page.screenshot(path=ARTIFACTS / name, full_page=True)


def test_the_folders_and_their_files_beside_the_library(clean: ShareShop) -> None:
    page = clean.shop.login("admin")
    page.get_by_role("link", name="Net share").click()
    page.wait_for_url(clean.shop.url + "/netshare")
    sync_api.expect(page.locator("h1")).to_contain_text("times in Europe/Berlin")
    facts = page.locator(".share-facts")
    sync_api.expect(facts).to_contain_text(str(clean.nas))
    for machine in clean.shares:
        sync_api.expect(facts.get_by_role("link", name=machine, exact=True)).to_have_attribute(
            "href", f"/machines/{machine}"
        )
    sync_api.expect(facts).to_contain_text("daily at 18:00")
    for key, folder in [("nas", clean.nas), *clean.shares.items()]:
        heading = page.locator(f"#folder-{key}-h")
        sync_api.expect(heading).to_contain_text(str(folder))
        rows = {r["name"]: r for r in page.evaluate(ROWS_JS, key)}
        assert set(NAS) <= set(rows), (key, sorted(rows))
        for name, data in NAS.items():
            row = rows[name]
            assert row["size"] == f"{len(data)} B", row
            assert row["bytes"] == f"{len(data):,} bytes", row
            assert row["match"].startswith(EXPECTED[name]), row
            assert hashlib.sha256(data).hexdigest()[:8] in row["match"], row
            # local time with the zone; the instant with its offset in the markup
            assert re.fullmatch(r"\d{4}-\d\d-\d\d \d\d:\d\d:\d\d CES?T", row["when"]), row
            assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\+0[12]:00", row["iso"]), row
        if key == "nas":  # the copies are as new as the push; the originals keep their time
            assert {rows[n]["when"] for n in NAS} == {WRITTEN_BERLIN}
        # the draft's bytes are its v1; the folded name links to the library's own name
        assert "is v1 (draft)" in rows["O02000.nc"]["match"]
        assert rows["o06000.NC"]["href"] == "/library/O06000.nc"
        assert rows["O05000.nc"]["href"] is None
    # every copy is in the share's recent activity, with the machine it went to
    done = page.evaluate(ACTIVITY_JS)
    pushed = {(r["machine"], r["file"].split()[0]) for r in done if r["what"] == "pushed"}
    assert {(m, n) for m in clean.shares for n in NAS} <= pushed, done
    firsts = {r["machine"] for r in done if r["what"].startswith("first look")}
    assert firsts == set(clean.shares), done
    page.context.close()


def test_a_file_dropped_on_the_nas_appears_while_the_page_is_open(clean: ShareShop) -> None:
    page = clean.shop.login("viewer")
    page.goto(clean.shop.url + "/netshare")
    sync_api.expect(page.locator("#folder-nas-h")).to_be_visible()
    data = b"%\r\nO07000 (LATE CHANGE)\r\nG20\r\nM30\r\n%\r\n"
    (clean.nas / "O07000.nc").write_bytes(data)
    # no reload: the push's event makes the page fetch its folders again
    for machine in clean.shares:
        section = page.locator(f"section[aria-labelledby='folder-{machine}-h']")
        sync_api.expect(section.locator("td.name", has_text="O07000.nc")).to_have_count(1)
    row = page.locator("section[aria-labelledby='folder-nas-h'] tr", has_text="O07000.nc")
    sync_api.expect(row.locator("td.match")).to_contain_text("not in library")
    sync_api.expect(row.locator("td.size")).to_have_text(f"{len(data)} B")
    page.context.close()


@pytest.mark.parametrize("viewport", WIDTHS, ids=lambda v: f"{v[0]}")
def test_read_only_no_overflow_and_no_word_broken(clean: ShareShop, viewport: Any) -> None:
    page = clean.shop.login("viewer", viewport=viewport)
    page.goto(clean.shop.url + "/netshare")
    sync_api.expect(page.locator(".share-activity tbody tr").first).to_be_visible()
    # a viewer's page, like everyone's: it shows, it changes nothing
    controls = page.locator("main button, main input, main select, main textarea, main form")
    assert controls.count() == 0
    problems = page.evaluate(MEASURE, [WHOLE, SCROLLERS])
    _shoot(page, f"netshare-{viewport[0]}.png")
    assert problems == [], (viewport, problems)
    page.context.close()


def test_without_a_net_share_the_page_says_how_to_add_one(
    tmp_path: Path, served: ShareShop
) -> None:
    with serve_one_tnc(tmp_path, "viewer", Role.VIEWER, PASSWORDS["viewer"]) as bare:
        shop = Shop(bare.url, bare.fleet, None, served.shop.browser)  # type: ignore[arg-type]
        page = shop.login("viewer")
        page.get_by_role("link", name="Net share").click()
        note = page.locator("main p.share-none")
        sync_api.expect(note).to_contain_text("No net share is configured")
        sync_api.expect(note).to_contain_text("[netshare]")
        sync_api.expect(note.locator("code").nth(2)).to_have_text('machines = ["HAAS-NGC"]')
        assert page.locator("main table, main section").count() == 0
        assert page.evaluate(MEASURE, [WHOLE, SCROLLERS]) == []
        _shoot(page, "netshare-none-1280.png")
        assert shop.problems == [], shop.problems
        page.context.close()


# -- the program page --------------------------------------------------------------------

BOXES_JS = """() => {
  const box = e => { const r = e.getBoundingClientRect();
    return {left: r.left, right: r.right, top: r.top + scrollY, bottom: r.bottom + scrollY}; };
  const main = document.querySelector('main'), style = getComputedStyle(main);
  const send = document.querySelector('section.send');
  return {
    content: {left: box(main).left + parseFloat(style.paddingLeft),
              right: box(main).right - parseFloat(style.paddingRight)},
    send: send ? box(send) : null,
    sections: [...main.querySelectorAll('section')]
      .filter(s => !s.classList.contains('send') && !s.closest('section.send')
                   && !s.parentElement.closest('section'))
      .map(s => ({id: s.getAttribute('aria-labelledby'), ...box(s)})),
  };
}"""


def _program(page: Any, url: str) -> dict[str, Any]:
    page.goto(url + "/library/O01000.nc")
    checks = page.locator("#machine-checks")
    if checks.count():  # its height is known once the checks are in
        sync_api.expect(checks).not_to_contain_text("Checking")
    sync_api.expect(page.locator(".listing-section")).to_be_visible()
    boxes: dict[str, Any] = page.evaluate(BOXES_JS)
    return boxes


def test_the_send_panel_and_the_page_beside_it_fill_the_row(clean: ShareShop) -> None:
    page = clean.shop.login("admin")
    boxes = _program(page, clean.shop.url)
    send, content = boxes["send"], boxes["content"]
    _shoot(page, "program-1280.png")
    assert page.evaluate(MEASURE, [WHOLE, SCROLLERS]) == []
    # the panel at the right edge; what is beside it starts at the left edge and reaches the
    # panel (the grid's 1 rem gap)
    assert abs(send["right"] - content["right"]) <= 1, boxes
    beside = [s for s in boxes["sections"] if s["right"] <= send["left"] + 1]
    assert beside, boxes
    assert min(s["left"] for s in beside) <= content["left"] + 1, boxes
    assert send["left"] - max(s["right"] for s in beside) <= 20, boxes
    # and from the panel's top to its bottom, no stretch beside it is left empty (at most the
    # space between two sections)
    edge, gaps = send["top"], []
    for s in sorted(beside, key=lambda s: s["top"]):
        if s["bottom"] <= send["top"]:
            continue
        gaps.append(s["top"] - edge)
        edge = max(edge, s["bottom"])
        if edge >= send["bottom"]:
            break
    assert edge >= send["bottom"], ("nothing beside the panel's lower part", boxes)
    assert max(gaps) <= 40, (gaps, boxes)
    # the panel stays in view along the program's text
    page.locator(".listing-section").scroll_into_view_if_needed()
    page.evaluate("window.scrollTo(0, document.documentElement.scrollHeight)")
    panel = page.locator("section.send").bounding_box()
    assert panel is not None
    assert panel["y"] >= 0, panel
    assert panel["y"] + panel["height"] <= 800 + 1, panel
    page.context.close()


def test_a_viewer_gets_the_whole_width_and_768_puts_the_panel_under_the_versions(
    clean: ShareShop,
) -> None:
    page = clean.shop.login("viewer")
    boxes = _program(page, clean.shop.url)
    _shoot(page, "program-viewer-1280.png")
    assert boxes["send"] is None
    for s in boxes["sections"]:  # no column kept for a panel a viewer does not have
        assert abs(s["right"] - boxes["content"]["right"]) <= 1, (s, boxes)
    page.context.close()

    page = clean.shop.login("admin", viewport=(768, 1024))
    boxes = _program(page, clean.shop.url)
    _shoot(page, "program-768.png")
    assert page.evaluate(MEASURE, [WHOLE, SCROLLERS]) == []
    send = boxes["send"]
    by_id = {s["id"]: s for s in boxes["sections"]}
    assert by_id["versions-h"]["bottom"] <= send["top"] <= by_id["check-h"]["top"], boxes
    for s in [send, *boxes["sections"]]:
        assert abs(s["left"] - boxes["content"]["left"]) <= 1, (s, boxes)
        assert abs(s["right"] - boxes["content"]["right"]) <= 1, (s, boxes)
    page.context.close()


def test_a_foreign_file_on_a_machine_is_replaced_by_the_released_version_in_one_click(
    clean: ShareShop,
) -> None:
    """A file on a machine that is not the released version: one click sends the released
    one there, through the queue (its policy, its audit row)."""
    released = b"%\r\nO08000 (CHAMFER)\r\nG20\r\nG01 X0.5 F10.\r\nM30\r\n%\r\n"
    page = clean.shop.login("admin")
    # the library's released O08000.nc, and an operator's own edit of it on haas-2
    page.goto(clean.shop.url + "/library")
    share = clean.shares["haas-2"]
    reply = page.request.post(
        clean.shop.url + "/library",
        multipart={
            "file": {"name": "O08000.nc", "mimeType": "text/plain", "buffer": released},
            "name": "O08000.nc",
        },
        headers={"X-CSRF-Token": _csrf(page)},
    )
    assert reply.ok, reply.text()
    released_reply = page.request.post(
        clean.shop.url + "/library/O08000.nc/versions/1/release",
        headers={"X-CSRF-Token": _csrf(page)},
    )
    assert released_reply.ok, released_reply.text()
    (share / "O08000.nc").write_bytes(released.replace(b"F10.", b"F25."))
    page.goto(clean.shop.url + "/netshare")
    section = page.locator("section[aria-labelledby='folder-haas-2-h']")
    row = section.locator("tr", has_text="O08000.nc")
    sync_api.expect(row.locator("td.match")).to_contain_text("differs from released v1")
    _shoot(page, "netshare-replace-1280.png")
    row.get_by_role("button", name="Replace with released v1").click()
    sync_api.expect(page.locator("#share-result")).to_contain_text("Queued: haas-2")
    wait_for(
        "the released version in the share", lambda: (share / "O08000.nc").read_bytes() == released
    )
    sync_api.expect(row.locator("td.match")).to_contain_text("same as released v1")
    page.context.close()


def _csrf(page: Any) -> str:
    token = page.evaluate("JSON.parse(document.body.getAttribute('hx-headers'))['X-CSRF-Token']")
    return str(token)
