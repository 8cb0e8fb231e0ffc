"""Program names that Windows or an SMB share would make one file are refused (issue 20 item 11),
and a database that cannot be reached at start is one line, not a traceback."""

from __future__ import annotations

import hashlib
import os
import socket
import subprocess
import sys
import threading
from datetime import UTC, datetime
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st
from sqlalchemy import Engine, event, text
from sqlalchemy.orm import Session, sessionmaker

from opendnc.errors import InputError
from opendnc.server.core.errors import Conflict, NotFound
from opendnc.server.library import versions as library
from opendnc.server.store.db import (
    current_revision,
    head_revision,
    make_engine,
    make_sessions,
    migrate,
)
from tests.server.harness import wait_for


@pytest.mark.parametrize("name", ["O1.nc.", "O1.nc..", "PART.", "O1.nc ", "O1 .nc", " O1.nc"])
def test_a_name_with_a_trailing_dot_or_a_space_is_refused(name: str) -> None:
    with pytest.raises(InputError) as caught:
        library.check_program_name(name)
    assert "\n" not in str(caught.value)
    if name.endswith(".") and ".." not in name:
        assert f"call it {name.rstrip('.')!r}" in str(caught.value)


@given(st.text(max_size=120))
def test_every_accepted_name_is_its_own_file_name_everywhere(name: str) -> None:
    try:
        accepted = library.check_program_name(name)
    except InputError:
        return
    assert accepted == name
    # Windows strips trailing dots and spaces; an accepted name has none to strip.
    assert name.rstrip(". ") == name
    assert "/" not in name
    assert "\\" not in name


def test_a_name_differing_only_in_case_is_refused_naming_the_one_that_exists(
    sessions: sessionmaker[Session],
) -> None:
    with sessions.begin() as session:
        library.add_version(session, "O1.nc", b"G0 X0\n", author="ann")
    for other in ("o1.nc", "O1.NC", "o1.Nc"):
        with sessions.begin() as session, pytest.raises(Conflict) as caught:
            library.add_version(session, other, b"G0 X1\n", author="bob")
        assert "'O1.nc'" in str(caught.value)
        assert "only in case" in str(caught.value)
    with sessions.begin() as session:  # the existing name itself takes new versions
        version, created = library.add_version(session, "O1.nc", b"G0 X2\n", author="bob")
        assert (version.number, created) == (2, True)
    with sessions() as session:
        assert [p.name for p in library.list_programs(session)] == ["O1.nc"]


def test_a_search_longer_than_a_name_is_refused_and_wildcards_match_themselves(
    sessions: sessionmaker[Session],
) -> None:
    with sessions.begin() as session:
        library.add_version(session, "A_1.nc", b"G0\n", author="ann")
        library.add_version(session, "AB1.nc", b"G0\n", author="ann")
    with sessions() as session:
        assert [p.name for p in library.list_programs(session, "a_")] == ["A_1.nc"]
        assert library.list_programs(session, "%") == []
        with pytest.raises(InputError):
            library.list_programs(session, "a" * 60000)


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
    return port


@pytest.mark.parametrize("command", ["serve", "keys"])
def test_an_unreachable_database_at_start_is_one_line(tmp_path: Path, command: str) -> None:
    config = tmp_path / "shop.toml"
    config.write_text(f'[server]\nbind = "127.0.0.1:0"\n[library]\npath = "{tmp_path / "lib"}"\n')
    url = f"postgresql+psycopg://postgres@127.0.0.1:{_closed_port()}/opendnc"
    args = ["serve"] if command == "serve" else ["keys", "create", "--role", "admin"]
    done = subprocess.run(
        [sys.executable, "-m", "opendnc.cli.main", *args, "--config", str(config), "--db", url],
        capture_output=True,
        text=True,
        timeout=60,
        env={**os.environ, "COLUMNS": "80"},  # a narrow terminal must not wrap it
        check=False,
    )
    assert done.returncode == 1, done.stderr
    (line,) = done.stderr.strip().splitlines()
    assert line.startswith(f"error: cannot reach the database {url}: "), line
    assert "refused" in line.lower()


def test_the_list_has_each_programs_newest_and_released_version_in_queries_that_do_not_grow(
    sessions: sessionmaker[Session], engine: Engine
) -> None:
    with sessions.begin() as session:
        library.add_version(session, "EMPTY.nc", b"G0\n", author="ann")
        for n in range(1, 4):
            library.add_version(session, "B.nc", f"G0 X{n}\n".encode(), author="ann")
        library.release(session, "B.nc", 2, actor="ann")
        library.add_version(session, "A.nc", b"G0 Y1\n", author="bob")
        library.release(session, "A.nc", 1, actor="bob")
    statements: list[str] = []

    def note(*args: object) -> None:
        statements.append(str(args[2]))

    def listed() -> dict[str, tuple[int, int | None, int | None]]:
        statements.clear()
        event.listen(engine, "before_cursor_execute", note)
        try:
            with sessions() as session:
                found = library.list_programs(session)
                return {
                    p.name: (
                        p.count,
                        p.newest.number if p.newest else None,
                        p.released.number if p.released else None,
                    )
                    for p in found
                }
        finally:
            event.remove(engine, "before_cursor_execute", note)

    before = listed()
    assert list(before) == ["A.nc", "B.nc", "EMPTY.nc"]  # by name
    assert before == {"A.nc": (1, 1, 1), "B.nc": (3, 3, 2), "EMPTY.nc": (1, 1, None)}
    queries = len(statements)
    with sessions.begin() as session:
        for n in range(4, 40):
            library.add_version(session, "B.nc", f"G0 X{n}\n".encode(), author="ann")
        library.release(session, "B.nc", 39, actor="ann")
    after = listed()
    assert after["B.nc"] == (39, 39, 39)
    assert len(statements) == queries
    with sessions() as session:
        assert [p.name for p in library.list_programs(session, "b.")] == ["B.nc"]
        b = library.list_programs(session, "b.")[0]
        assert b.newest is not None
        assert b.newest.program.name == "B.nc"


def test_a_programs_history_gives_its_newest_versions_oldest_first_and_the_count(
    sessions: sessionmaker[Session],
) -> None:
    with sessions.begin() as session:
        for n in range(1, 6):
            library.add_version(session, "H.nc", f"G0 X{n}\n".encode(), author=f"u{n}")
        library.release(session, "H.nc", 4, actor="boss")
    with sessions() as session:
        newest = library.history(session, "H.nc", limit=2)
        everything = library.history(session, "H.nc")
        with pytest.raises(NotFound):
            library.history(session, "h.nc")
    assert newest.count == everything.count == 5
    assert [v.number for v in newest.versions] == [4, 5]
    assert [v.number for v in everything.versions] == [1, 2, 3, 4, 5]
    assert [v.state.value for v in everything.versions] == [
        "draft",
        "draft",
        "draft",
        "released",
        "draft",
    ]
    assert newest.versions[0].author == "u4"
    assert newest.versions[1].sha256 == hashlib.sha256(b"G0 X5\n").hexdigest()
    assert newest.versions[1].created.tzinfo is not None


def test_two_uploads_of_case_twins_at_the_same_moment_leave_one_program_and_a_409(
    sessions: sessionmaker[Session], engine: Engine
) -> None:
    # The first upload has inserted its program and not committed yet when the second checks
    # for a case twin: on PostgreSQL the check cannot see it, the unique index on the folded
    # name makes the second wait for the first and then refuses it.
    outcome: dict[str, object] = {}
    first = sessions()
    first.begin()
    library.add_version(first, "a.nc", b"G0 X1\n", author="ann")

    def second() -> None:
        try:
            with sessions.begin() as session:
                library.add_version(session, "A.nc", b"G0 X2\n", author="bob")
            outcome["second"] = "stored"
        except Conflict as exc:
            outcome["second"] = str(exc)

    racer = threading.Thread(target=second)
    racer.start()
    if engine.dialect.name == "postgresql":
        # Commit only once the second upload waits for the first's row in the index.
        waiting = text(
            "SELECT count(*) FROM pg_stat_activity WHERE datname = current_database() "
            "AND wait_event_type = 'Lock'"
        )

        def lock_waits() -> int:
            # each poll in a transaction of its own: a backend reads pg_stat_activity once a
            # transaction, so a first poll made before the second upload waited saw no wait
            # for as long as the test asked (seen under load in CI)
            with engine.connect() as conn:
                return int(conn.execute(waiting).scalar_one())

        wait_for("the second upload to wait", lock_waits)
    first.commit()
    first.close()
    racer.join(60)
    assert not racer.is_alive()
    assert "only in case" in str(outcome["second"]), outcome
    with sessions() as session:
        assert [p.name for p in library.list_programs(session)] == ["a.nc"]


def test_a_database_that_holds_case_twins_migrates_without_the_index(db_url: str) -> None:
    engine = make_engine(db_url)
    try:
        migrate(engine, "0007")
        with engine.begin() as conn:
            for name in ("x.nc", "X.nc", "y.nc"):
                conn.execute(
                    text("INSERT INTO programs (name, locked, created) VALUES (:n, :l, :c)"),
                    {"n": name, "l": False, "c": datetime.now(UTC)},
                )
        migrate(engine)
        assert current_revision(engine) == head_revision()
        with engine.connect() as conn:
            names = conn.execute(text("SELECT name FROM programs ORDER BY name")).scalars()
            assert list(names) == ["X.nc", "x.nc", "y.nc"]
        with make_sessions(engine).begin() as session, pytest.raises(Conflict):
            library.add_version(session, "Y.nc", b"G0\n", author="ann")  # the check still refuses
    finally:
        engine.dispose()
