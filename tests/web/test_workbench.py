"""The program workbench in Debian's Chromium (Playwright): the program check's problem list
with links to its lines, the send form's check per machine and the override, the editor
(highlighting, search and replace, go to line, save as a checked draft) and the word diff.

The programs are written here with their defects and changes on known lines. Screenshots at
1280×800 and 768 wide go to ``tests/artifacts/screenshots`` (gitignored) for a person to
look at."""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import select

from tests.peers import require_module

require_module("playwright.sync_api")

from opendnc.server.library import versions as library  # noqa: E402
from opendnc.server.store.models import AuditEntry, Role  # noqa: E402
from opendnc.server.web import session as web_session  # noqa: E402
from tests.server.inprocess_app import App, running  # noqa: E402
from tests.web.browser import ARTIFACTS, TIMEOUT_MS, chromium, sync_api  # noqa: E402

expect = sync_api.expect

MACHINES: list[dict[str, object]] = [
    {"name": "tnc-1", "kind": "lsv2", "host": "127.0.0.1", "port": 1},
    {"name": "haas-1", "kind": "haas_serial", "serial": "socket://127.0.0.1:1"},
]


def _haas_program(lines: int) -> bytes:
    """A clean Haas program of about ``lines`` lines: a tool, a macro variable, a pocket of
    feed moves (line k holds ``X{k}.``), then the end."""
    head = [
        "%",
        "O02000 (POCKET)",
        "(T1 10MM END MILL)",
        "T1 M06",
        "#100 = 2.5",
        "G00 G90 G54 X0. Y0.",
        "S2000 M03",
        "G43 H01 Z5.",
        "G01 Z-#100 F100.",
    ]
    body = [f"G01 X{k}. Y{k % 7}. F100." for k in range(len(head) + 1, lines - 3)]
    tail = ["G00 Z50.", "M30", "%"]
    return ("\n".join(head + body + tail) + "\n").encode()


KLARTEXT = (
    b"0 BEGIN PGM K MM\n"
    b"1 BLK FORM 0.1 Z X+0 Y+0 Z-20\n"
    b"2 BLK FORM 0.2 X+100 Y+100 Z+0\n"
    b"3 TOOL CALL 5 Z S3000\n"
    b"4 FN 0: Q1 = +10 ; depth\n"
    b"5 L X+10 Y-5 R0 FMAX M3\n"
    b"6 L Z-Q1 F200\n"
    b"7 END PGM K MM\n"
)
# two defects on known lines: an unknown G code on line 5, a word without a value on line 7
BROKEN = (
    b"%\nO02001 (BROKEN)\nT1 M06\nG00 G90 G54 X0. Y0.\nG999 X1.\nS1000 M03\nG01 X F100.\nM30\n%\n"
)


@pytest.fixture(scope="module")
def app(tmp_path_factory: pytest.TempPathFactory) -> Iterator[App]:
    with running(tmp_path_factory.mktemp("workbench"), MACHINES) as served:
        with served.server.sessions.begin() as s:
            library.add_version(s, "O02000.nc", _haas_program(300), author="ann")
            library.add_version(s, "K.H", KLARTEXT, author="ann")
            library.add_version(s, "O02001.nc", BROKEN, author="ann")
        yield served


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    with chromium() as found:
        yield found


class Tab:
    """A logged-in browser page, with the console errors it saw."""

    def __init__(self, app: App, browser: Any, role: Role, width: int, height: int) -> None:
        self.base = str(app.client.base_url).rstrip("/")
        self.ctx = browser.new_context(viewport={"width": width, "height": height})
        self.ctx.set_default_timeout(TIMEOUT_MS)
        self.ctx.add_cookies(
            [{"name": web_session.COOKIE, "value": app.session_keys[role], "url": self.base}]
        )
        self.problems: list[str] = []

        def route(r: Any) -> None:
            if r.request.url.startswith(self.base):
                r.continue_()
            else:
                self.problems.append(f"request left the machine: {r.request.url}")
                r.abort()

        self.ctx.route("**/*", route)
        self.page = self.ctx.new_page()
        self.page.on("console", self._console)
        self.page.on("pageerror", lambda e: self.problems.append(f"page error: {e}"))

    def _console(self, message: Any) -> None:
        # a refusal (409, 400) is the browser's own console line, not a script's error
        if message.type == "error" and "status of 4" not in message.text:
            self.problems.append(f"console: {message.text}")

    def goto(self, path: str) -> Any:
        self.page.goto(self.base + path)
        return self.page

    def shot(self, name: str) -> None:
        ARTIFACTS.mkdir(parents=True, exist_ok=True)
        self.page.screenshot(path=str(ARTIFACTS / f"wbcheck-{name}.png"), full_page=True)

    def close(self) -> None:
        self.ctx.close()
        assert not self.problems, self.problems


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


def test_a_problem_opens_the_editor_at_its_line(app: App, browser: Any) -> None:
    tab = Tab(app, browser, Role.PROGRAMMER, 1280, 800)
    page = tab.goto("/library/O02001.nc")
    page.get_by_role("link", name="Edit at line 7").click()
    page.wait_for_url("**/versions/1/edit#L7")
    expect(page.locator("#ed-status")).to_contain_text("Line 7, column 1")
    expect(page.locator(".ed-gutter .cur")).to_have_text("7")
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


def _visible_lines(page: Any) -> list[str]:
    text: str = page.locator(".ed-view code").inner_text()
    return text.rstrip("\n").split("\n")


def test_the_editor_searches_replaces_goes_to_a_line_and_saves_a_checked_draft(
    app: App, browser: Any
) -> None:
    tab = Tab(app, browser, Role.PROGRAMMER, 1280, 800)
    page = tab.goto("/library/O02000.nc")
    page.get_by_role("link", name="Edit v1").click()
    page.wait_for_url("**/versions/1/edit")
    area = page.get_by_role("textbox", name="Text of O02000.nc")
    original = area.input_value()
    assert original.encode() == _haas_program(300)
    # highlighted: addresses by letter, the macro variable, the comment; only lines in view
    view = page.locator(".ed-view")
    expect(view.locator(".hl-g").first).to_have_text("G00")
    expect(view.locator(".hl-v").first).to_have_text("#100")
    expect(view.locator(".hl-c")).to_have_text(["(POCKET)", "(T1 10MM END MILL)"])
    expect(view.locator(".hl-t").first).to_have_text("T1")
    expect(view.locator(".hl-m").first).to_have_text("M06")
    shown = _visible_lines(page)
    assert shown[:2] == ["%", "O02000 (POCKET)"]
    assert len(shown) < 60  # of 300

    # go to line 250: the caret is there and the view shows it
    page.get_by_label("Go to line").fill("250")
    page.get_by_role("button", name="Go", exact=True).click()
    expect(page.locator("#ed-status")).to_contain_text("Line 250, column 1")
    expect(page.locator(".ed-gutter .cur")).to_have_text("250")
    assert "G01 X250. Y5. F100." in _visible_lines(page)

    # find: from the caret on
    page.get_by_label("Find").fill("X260.")
    page.get_by_role("button", name="Find next").click()
    expect(page.locator("#ed-found")).to_have_text("Found on line 260")
    expect(page.locator(".ed-mark.hit")).to_have_count(1)
    # replace one: the found word, then the next is found
    page.get_by_label("Replace with").fill("X-5.")
    page.get_by_role("button", name="Replace", exact=True).click()
    assert "G01 X-5. Y1. F100." in area.input_value().split("\n")
    # replace all: every feed of 100 becomes 150 (one per line from line 9 to 296)
    page.get_by_label("Find").fill("F100.")
    page.get_by_label("Replace with").fill("F150.")
    page.get_by_role("button", name="Replace all").click()
    expect(page.locator("#ed-found")).to_have_text(f"{original.count('F100.')} replaced")
    assert "F100." not in area.input_value()
    # a defect typed in by hand: the M30 on line 298 becomes M300, so the program has no end
    page.get_by_label("Go to line").fill("298")
    page.get_by_role("button", name="Go", exact=True).click()
    edited = area.input_value().split("\n")
    assert edited[297] == "M30"
    page.keyboard.press("End")
    page.keyboard.type("0")  # M300
    expect(page.locator("#ed-status")).to_contain_text("changed")
    tab.shot("editor-1280")

    page.get_by_label("Comment").fill("feed 150, no M30 on purpose")
    page.get_by_role("button", name="Save as new draft").click()
    page.wait_for_url("**/library/O02000.nc?v=2#check")
    expect(page.locator("tr.current")).to_contain_text("feed 150, no M30 on purpose")
    expect(page.locator("tr.current")).to_contain_text("draft")
    problems = page.get_by_role("list", name="Problems of O02000.nc v2")
    expect(problems.get_by_role("listitem")).to_have_count(1)
    expect(problems).to_contain_text("O02000.nc:298")
    expect(problems).to_contain_text("no program end")
    tab.shot("saved-draft-1280")
    tab.close()
    with app.server.sessions() as s:
        version = library.get_version(s, "O02000.nc", 2)
        saved = library.content(s, version).decode()
    assert (version.comment, version.author, version.source) == (
        "feed 150, no M30 on purpose",
        "programmer",
        "editor",
    )
    assert saved.count("F150.") == original.count("F100.")
    assert "\r" not in saved
    assert "\nM300\n" in saved


def test_the_editor_highlights_klartext_at_768_wide(app: App, browser: Any) -> None:
    tab = Tab(app, browser, Role.PROGRAMMER, 768, 1024)
    page = tab.goto("/library/K.H/versions/1/edit")
    view = page.locator(".ed-view")
    keywords = view.locator(".hl-k").all_inner_texts()
    assert keywords[:3] == ["BEGIN", "PGM", "MM"]
    assert {"TOOL", "CALL", "BLK", "FORM", "FN", "FMAX", "R0"} <= set(keywords)
    assert view.locator(".hl-v").all_inner_texts() == ["Q1"]  # Z-Q1 is a coordinate
    coordinates = view.locator(".hl-ax").all_inner_texts()
    assert {"X+0", "Y+0", "Z-20", "X+10", "Y-5"} <= set(coordinates)
    assert view.locator(".hl-c").all_inner_texts() == ["; depth"]
    assert view.locator(".hl-n").all_inner_texts()[:3] == ["0", "1", "2"]
    tab.shot("editor-768")
    overflow = page.evaluate("document.documentElement.scrollWidth > window.innerWidth")
    assert not overflow
    tab.close()


def test_the_diff_marks_changed_words_and_counts_the_skipped_lines(app: App, browser: Any) -> None:
    old = _haas_program(300)
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


def test_the_editor_is_for_programmers(app: App, tmp_path: Path) -> None:
    reply = app.client.get(
        "/library/K.H/versions/1/edit", headers=app.page(Role.OPERATOR), follow_redirects=False
    )
    assert reply.status_code == 403
    saved = app.client.post(
        "/library/K.H/versions/1/edit",
        data={"text": "x", "comment": "c"},
        headers=app.page(Role.OPERATOR),
    )
    assert saved.status_code == 403
    blank = app.client.post(
        "/library/K.H/versions/1/edit",
        data={"text": KLARTEXT.decode(), "comment": " "},
        headers=app.page(Role.PROGRAMMER),
    )
    assert blank.status_code == 400
    assert "comment" in blank.text


def test_a_program_of_20000_lines_is_edited_with_only_the_lines_in_view_drawn(
    app: App, browser: Any
) -> None:
    big = _haas_program(20_000)
    with app.server.sessions.begin() as s:
        library.add_version(s, "O04000.nc", big, author="ann")
    tab = Tab(app, browser, Role.PROGRAMMER, 1280, 800)
    page = tab.goto("/library/O04000.nc/versions/1/edit")
    expect(page.locator("#ed-status")).to_contain_text("20,000 lines")
    page.get_by_label("Go to line").fill("19500")
    page.get_by_role("button", name="Go", exact=True).click()
    expect(page.locator(".ed-gutter .cur")).to_have_text("19500")
    shown = _visible_lines(page)
    assert "G01 X19500. Y5. F100." in shown
    assert len(shown) < 60
    assert page.locator(".ed-gutter-lines div").count() < 60
    # typing at the end of that line changes the text and the drawn line alike
    page.keyboard.press("End")
    page.keyboard.type(" (HERE)")
    expect(page.locator(".ed-view")).to_contain_text("G01 X19500. Y5. F100. (HERE)")
    assert (
        page.get_by_role("textbox", name="Text of O04000.nc")
        .input_value()
        .split("\n")[19499]
        .endswith("(HERE)")
    )
    tab.close()
