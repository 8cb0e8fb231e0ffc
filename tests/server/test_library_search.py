"""The library list's titles and sizes, the search in the programs' text (SQLite and
PostgreSQL: any case, wildcards matching themselves, the newest version only, bounded), and a
control's file taken back into the library as a new draft (a receive job, programmers)."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from sqlalchemy.orm import Session, sessionmaker

from opendnc.server.library import versions as library
from opendnc.server.store.models import Role
from tests.server.harness import wait_for
from tests.server.inprocess_app import App, running

BRACKET = b"%\nO1000 (BRACKET OP1)\nT12 M6\nG84 Z-10. R2. F1.25\nM30\n%\n"
POCKET = (
    b"0 BEGIN PGM POCKET MM\r\n1 ; POCKET 40X20\r\n2 TOOL CALL 5 Z S4000\r\n3 END PGM POCKET MM\r\n"
)
ODD = b"O2000 (ODD)\n(100% FEED_RATE \\ CHECK)\nM30\n"


def _fill(sessions: sessionmaker[Session]) -> None:
    with sessions.begin() as session:
        library.add_version(session, "O1000.nc", BRACKET, author="ann")
        library.add_version(session, "POCKET.H", POCKET, author="ann")
        library.add_version(session, "O2000.nc", b"O2000 (OLD)\nT12 M6\n", author="ann")
        library.add_version(session, "O2000.nc", ODD, author="ann")  # v2: T12 no longer


def _hits(sessions: sessionmaker[Session], text: str) -> list[tuple[str, int, str]]:
    with sessions() as session:
        return [(h.name, h.line, h.text) for h in library.search_text(session, text)]


def test_the_text_search_finds_lines_in_any_case_in_the_newest_versions(
    sessions: sessionmaker[Session],
) -> None:
    _fill(sessions)
    assert _hits(sessions, "t12 m6") == [("O1000.nc", 3, "T12 M6")]
    assert _hits(sessions, "tool call 5") == [("POCKET.H", 3, "2 TOOL CALL 5 Z S4000")]
    assert _hits(sessions, "M30") == [("O1000.nc", 5, "M30"), ("O2000.nc", 3, "M30")]
    assert _hits(sessions, "G84 Z-10.") == [("O1000.nc", 4, "G84 Z-10. R2. F1.25")]


@pytest.mark.parametrize(
    ("text", "found"),
    [
        ("100%", ["O2000.nc"]),
        ("0% f", ["O2000.nc"]),
        ("%", ["O1000.nc", "O2000.nc"]),  # the % lines of O1000 and the 100% of O2000
        ("_RATE", ["O2000.nc"]),
        ("D_R", ["O2000.nc"]),  # FEED_RATE
        ("\\ CH", ["O2000.nc"]),
        ("\\", ["O2000.nc"]),
        ("%_", []),
        ("X_0", []),  # would match "POCKET 40X20" if _ were a wildcard
    ],
)
def test_wildcards_and_backslashes_match_themselves(
    sessions: sessionmaker[Session], text: str, found: list[str]
) -> None:
    _fill(sessions)
    assert [name for name, _line, _text in _hits(sessions, text)] == found


def test_the_text_search_is_bounded(sessions: sessionmaker[Session]) -> None:
    with sessions.begin() as session:
        for i in range(library.MAX_TEXT_HITS + 5):
            library.add_version(session, f"P{i:04d}.nc", b"G0 X0\nM30\n", author="ann")
    with sessions() as session:
        hits = library.search_text(session, "m30")
    assert len(hits) == library.MAX_TEXT_HITS
    assert hits[0].name == "P0000.nc"


@pytest.fixture(scope="module")
def app(tmp_path_factory: pytest.TempPathFactory) -> Iterator[App]:
    machines: list[dict[str, object]] = [
        {"name": "tnc", "kind": "lsv2", "host": "127.0.0.1", "port": 1, "poll_interval": 0.2}
    ]
    with running(tmp_path_factory.mktemp("takeback"), machines) as served:
        _fill(served.server.sessions)
        yield served


def test_the_list_names_titles_and_sizes_and_q_searches_them(app: App) -> None:
    viewer = app.api(Role.VIEWER)
    listed = {p["name"]: p for p in app.client.get("/api/programs", headers=viewer).json()}
    assert listed["O1000.nc"]["title"] == "BRACKET OP1"
    assert listed["POCKET.H"]["title"] == "POCKET 40X20"
    assert listed["O2000.nc"]["title"] == "ODD"
    assert listed["O2000.nc"]["newest"]["size"] == len(ODD)
    by_title = app.client.get("/api/programs", params={"q": "bracket"}, headers=viewer).json()
    assert [p["name"] for p in by_title] == ["O1000.nc"]
    found = app.client.get("/api/programs", params={"text": "g84"}, headers=viewer).json()
    assert [(p["name"], p["match"]) for p in found] == [
        ("O1000.nc", {"line": 4, "text": "G84 Z-10. R2. F1.25"})
    ]
    both = app.client.get(
        "/api/programs", params={"q": "pocket", "text": "m30"}, headers=viewer
    ).json()
    assert both == []
    short = app.client.get("/api/programs", params={"text": "x"}, headers=viewer)
    assert short.status_code == 400
    assert "at least 2" in short.json()["detail"]
    page = app.client.get("/library", params={"text": "tool call"}, headers=app.page(Role.VIEWER))
    assert page.status_code == 200
    assert "POCKET.H" in page.text
    assert "O1000.nc" not in page.text
    assert "line 3" in page.text


def _job(app: App, job_id: int) -> dict[str, object]:
    reply = app.client.get(f"/api/jobs/{job_id}", headers=app.api(Role.VIEWER))
    return dict(reply.json())


def test_a_file_taken_back_becomes_a_new_draft_of_its_program(app: App) -> None:
    changed = BRACKET.replace(b"F1.25", b"F1.5")
    app.controls["tnc"].files["TNC:/nc_prog/O1000.nc"] = changed
    reply = app.client.post(
        "/api/machines/tnc/files/take-back",
        params={"path": "TNC:/nc_prog/O1000.nc"},
        headers=app.api(Role.PROGRAMMER),
    )
    assert reply.status_code == 201, reply.text
    job = reply.json()
    assert (job["kind"], job["params"]["into_library"]) == ("receive", True)
    wait_for("the take-back", lambda: _job(app, job["id"])["state"] == "done", timeout=30)
    with app.server.sessions() as session:
        program = library.get_program(session, "O1000.nc")
        newest = program.versions[-1]
        assert (newest.number, newest.state.value, newest.author) == (2, "draft", "programmer")
        assert library.content(session, newest) == changed


def test_a_take_back_into_a_locked_program_is_refused(app: App) -> None:
    with app.server.sessions.begin() as session:
        library.set_locked(session, "POCKET.H", True, actor="t")
    app.controls["tnc"].files["TNC:/nc_prog/POCKET.H"] = POCKET + b"; changed\r\n"
    reply = app.client.post(
        "/api/machines/tnc/files/take-back",
        params={"path": "TNC:/nc_prog/POCKET.H"},
        headers=app.api(Role.ADMIN),
    )
    assert reply.status_code == 409
    assert "locked" in reply.json()["detail"]
    operator = app.client.post(
        "/api/machines/tnc/files/take-back",
        params={"path": "TNC:/nc_prog/O1000.nc"},
        headers=app.api(Role.OPERATOR),
    )
    assert operator.status_code == 403
