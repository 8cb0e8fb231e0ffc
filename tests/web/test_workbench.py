"""The program workbench in Debian's Chromium (Playwright): the program check's problem list
with links to its lines, the send form's check per machine and the override, and the word
diff (the editor's tests are in test_editor.py).

The programs are written here with their defects and changes on known lines. Screenshots at
1280×800 and 768 wide go to ``tests/artifacts/screenshots`` (gitignored) for a person to
look at."""

from __future__ import annotations

import re
import time
from collections.abc import Iterator
from typing import Any

import pytest
from sqlalchemy import select

from tests.peers import require_module

require_module("playwright.sync_api")

from opendnc.server.library import versions as library  # noqa: E402
from opendnc.server.store.models import AuditEntry, Role  # noqa: E402
from tests.server.inprocess_app import App, running  # noqa: E402
from tests.web.browser import ARTIFACTS, chromium, sync_api  # noqa: E402
from tests.web.workbench_support import (  # noqa: E402
    BROKEN,
    KLARTEXT,
    MACHINES,
    Tab,
    haas_program,
)

expect = sync_api.expect


@pytest.fixture(scope="module")
def app(tmp_path_factory: pytest.TempPathFactory) -> Iterator[App]:
    with running(tmp_path_factory.mktemp("workbench"), MACHINES) as served:
        with served.server.sessions.begin() as s:
            library.add_version(s, "O02000.nc", haas_program(300), author="ann")
            library.add_version(s, "K.H", KLARTEXT, author="ann")
            library.add_version(s, "O02001.nc", BROKEN, author="ann")
        yield served


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    with chromium() as found:
        yield found


def test_the_program_page_lists_the_problems_with_links_to_their_lines(
    app: App, browser: Any
) -> None:
    for width, height in [(1280, 800), (768, 1024)]:
        tab = Tab(app, browser, Role.APPROVER, width, height)
        page = tab.goto("/library/O02001.nc")
        problems = page.get_by_role("list", name="Problems of O02001.nc v1")
        expect(problems.get_by_role("listitem")).to_have_count(2)
        first, second = problems.get_by_role("listitem").all()
        expect(first).to_contain_text("O02001.nc:5")
        expect(first).to_contain_text("G999")
        expect(second).to_contain_text("O02001.nc:7")
        expect(page.locator("#check-h")).to_contain_text("2 errors")
        # the link goes to the line in the text
        first.get_by_role("link", name="O02001.nc:5").click()
        assert page.url.endswith("#L5")
        expect(page.locator("#L5")).to_contain_text("G999 X1.")
        expect(page.locator("#L5")).to_have_class(re.compile(r"\bhl\b"))
        # an approver may release past the errors only with the box ticked and a reason
        expect(page.get_by_role("button", name="Release anyway")).to_be_visible()
        page.evaluate("window.scrollTo(0, 0)")
        tab.shot(f"program-problems-{width}")
        overflow = page.evaluate("document.documentElement.scrollWidth > window.innerWidth")
        assert not overflow
        tab.close()


def test_a_problems_link_clicked_before_the_text_has_come_marks_its_line_when_it_comes(
    app: App, browser: Any
) -> None:
    # Seen on a loaded machine: the click changed the hash while the listing's text was on
    # its way, and the line was never marked. The text is held back here until after it.
    tab = Tab(app, browser, Role.APPROVER, 1280, 800)
    held: list[Any] = []
    tab.page.route("**/library/O02001.nc/versions/1/download", lambda r: held.append(r))
    page = tab.goto("/library/O02001.nc")
    deadline = time.monotonic() + 30
    while not held and time.monotonic() < deadline:
        page.wait_for_timeout(20)  # lets Playwright hand over the held request
    assert len(held) == 1  # the text is on its way, and held there
    problems = page.get_by_role("list", name="Problems of O02001.nc v1")
    problems.get_by_role("link", name="O02001.nc:5").click()
    assert page.url.endswith("#L5")
    held[0].continue_()
    expect(page.locator("#L5")).to_contain_text("G999 X1.")
    expect(page.locator("#L5")).to_have_class(re.compile(r"\bhl\b"))
    tab.close()


def test_the_send_form_shows_each_machines_check_and_the_override_is_audited(
    app: App, browser: Any
) -> None:
    tab = Tab(app, browser, Role.PROGRAMMER, 1280, 800)
    page = tab.goto("/library/K.H")
    checks = page.locator("#machine-checks")
    expect(checks.locator("li[data-machine='tnc-1']")).to_contain_text("no errors")
    expect(checks.locator("li[data-machine='haas-1']")).to_contain_text("1 error")
    expect(checks.locator("li[data-machine='haas-1']")).to_contain_text(
        "heidenhain program cannot run"
    )
    # a Klartext program to the TNC and the Haas: queued on the TNC, and the Haas named in
    # the panel with the reason (it refused the whole send, named at the page's top)
    page.get_by_role("checkbox", name="haas-1").check()
    page.get_by_role("checkbox", name="tnc-1").check()
    page.once("dialog", lambda d: d.accept())  # two machines: asked first
    page.get_by_role("button", name="Send", exact=True).click()
    result = page.locator("#send-result")
    expect(result).to_contain_text("Queued: tnc-1")
    expect(result.locator(".refused li")).to_have_count(1)
    expect(result.locator(".refused li")).to_contain_text(
        "haas-1: K.H v1 to haas-1: the program check found 1 error"
    )
    expect(page.locator("#alert")).to_be_empty()
    tab.shot("send-refused")
    # the Haas alone: refused everywhere, said in the panel all the same
    page.get_by_role("checkbox", name="tnc-1").uncheck()
    page.get_by_role("button", name="Send", exact=True).click()
    expect(result.locator(".ok")).to_have_count(0)
    expect(result.locator(".refused")).to_contain_text("Not sent to 1 machine")
    # overridden with a reason: queued, and the history has who and why
    page.get_by_text("Override check errors").click()
    page.get_by_role("checkbox", name="Send although the check finds errors").check()
    page.get_by_label("Reason (kept in the history)").fill("test cut on the Haas, by hand")
    page.get_by_role("button", name="Send", exact=True).click()
    expect(page.locator("#send-result")).to_contain_text("Queued: haas-1")
    tab.shot("send-override")
    tab.close()
    with app.server.sessions() as s:
        rows = list(
            s.scalars(select(AuditEntry).where(AuditEntry.action == "program.check_override"))
        )
    assert [(r.actor, r.machine, r.program, r.detail["reason"]) for r in rows] == [
        ("programmer", "haas-1", "K.H", "test cut on the Haas, by hand")
    ]
    with app.server.sessions() as s:
        refused = list(s.scalars(select(AuditEntry).where(AuditEntry.action == "job.refused")))
    assert [(r.actor, r.machine, r.program) for r in refused] == [
        ("programmer", "haas-1", "K.H"),
        ("programmer", "haas-1", "K.H"),
    ]


def test_the_diff_marks_changed_words_and_counts_the_skipped_lines(app: App, browser: Any) -> None:
    old = haas_program(300)
    # line 150 changes one word, line 151 gains a comment; 140 lines before the first change
    # and 140 after the last are unchanged, each shortened to 3 lines of context
    lines = old.decode().split("\n")
    assert lines[149] == "G01 X150. Y3. F100."
    lines[149] = "G01 X150. Y4. F100."
    lines[150] = lines[150] + " (CHECK)"
    with app.server.sessions.begin() as s:
        library.add_version(s, "O03000.nc", old, author="ann")
        library.add_version(s, "O03000.nc", "\n".join(lines).encode(), author="ann")
    tab = Tab(app, browser, Role.VIEWER, 1280, 800)
    page = tab.goto("/library/O03000.nc?a=1&b=2")
    table = page.get_by_role("table", name="Changes from v1 to v2")
    expect(table.locator(".wd-del")).to_have_text(["Y3."])
    expect(table.locator(".wd-ins")).to_have_text(["Y4.", " (CHECK)"])
    # the skip rows are drawn across the table (not moved away like a skip link)
    table_box = table.bounding_box()
    for row in table.locator("tr.skipped").all():
        box = row.bounding_box()
        assert box["x"] >= table_box["x"]
        assert box["width"] > table_box["width"] / 2
    skips = table.locator("tr.skipped").all_inner_texts()
    total = len(old.decode().splitlines())
    assert skips == [
        "⋯ 146 unchanged lines ⋯",
        f"⋯ {total - 151 - 3:,} unchanged lines ⋯",
    ]
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    page.locator("section", has=table).screenshot(path=str(ARTIFACTS / "wbcheck-diff-1280.png"))
    tab.close()
