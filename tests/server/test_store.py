"""Migrations, the audit trail's append-only rule and the mapping of the models."""

from __future__ import annotations

import hashlib
import warnings

import pytest
from alembic.autogenerate import compare_metadata
from alembic.runtime.migration import MigrationContext
from alembic.script import ScriptDirectory
from sqlalchemy import Connection, Engine, inspect, text
from sqlalchemy.exc import DBAPIError, SAWarning

from opendnc.server.library import inbox
from opendnc.server.library import versions as library
from opendnc.server.store import audit
from opendnc.server.store.db import (
    MIGRATIONS,
    current_revision,
    head_revision,
    make_engine,
    make_sessions,
    migrate,
)
from opendnc.server.store.models import Base

FOLDED = "uq_programs_name_folded"


def _differences(conn: Connection) -> list[object]:
    """What Alembic finds between the models and the migrated schema.

    SQLAlchemy reflects no expression index on SQLite (it warns) and Alembic compares none,
    so the index on the folded program name is left to its own test below."""

    def include(_obj: object, name: str | None, kind: str, *_rest: object) -> bool:
        return not (kind == "index" and name == FOLDED)

    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", "Skipped unsupported reflection", SAWarning)
        warnings.filterwarnings("ignore", "autogenerate skipping .* expression-based index")
        context = MigrationContext.configure(conn, opts={"include_object": include})
        return list(compare_metadata(context, Base.metadata))


def _has_folded_index(conn: Connection) -> bool:
    if conn.dialect.name == "sqlite":
        query = "SELECT count(*) FROM sqlite_master WHERE type = 'index' AND name = :n"
    else:
        query = "SELECT count(*) FROM pg_indexes WHERE indexname = :n"
    return bool(conn.execute(text(query), {"n": FOLDED}).scalar())


def test_migrates_an_empty_database_to_head_and_back(db_url: str) -> None:
    engine = make_engine(db_url)
    try:
        assert current_revision(engine) is None
        migrate(engine)
        assert current_revision(engine) == head_revision()
        tables = set(inspect(engine).get_table_names())
        assert {
            "users",
            "api_keys",
            "machines",
            "programs",
            "program_versions",
            "blobs",
            "jobs",
            "audit",
        } <= tables
        migrate(engine, "base")
        assert current_revision(engine) is None
        assert "jobs" not in set(inspect(engine).get_table_names())
        migrate(engine)  # and up again from the previous revision
        assert current_revision(engine) == head_revision()
    finally:
        engine.dispose()


def test_models_match_the_migrations(engine: Engine) -> None:
    with engine.connect() as conn:
        differences = _differences(conn)
        assert _has_folded_index(conn)
    assert differences == []


def test_audit_rows_cannot_be_changed_or_deleted(engine: Engine, sessions) -> None:  # type: ignore[no-untyped-def]
    with sessions.begin() as session:
        audit.record(session, "alice", "login")
    for statement in ("UPDATE audit SET actor = 'mallory'", "DELETE FROM audit"):
        with pytest.raises(DBAPIError, match="append-only"), engine.begin() as conn:
            conn.execute(text(statement))
    with sessions() as session:
        rows = audit.query(session)
        assert [(r.actor, r.action) for r in rows] == [("alice", "login")]


def _program_and_audit_rows(conn: Connection) -> None:
    """The program O1.nc and an audit row of ann's, written as the older schemas have them."""
    conn.execute(
        text(
            "INSERT INTO programs (name, locked, created) "
            "VALUES ('O1.nc', false, CURRENT_TIMESTAMP)"
        )
    )
    conn.execute(
        text(
            "INSERT INTO audit (at, actor, action, result, detail) "
            "VALUES (CURRENT_TIMESTAMP, 'ann', 'login', 'ok', '{}')"
        )
    )


def test_upgrade_from_the_previous_revision_keeps_the_data(db_url: str) -> None:
    # A shop running the first schema upgrades: its library and audit trail come along.
    engine = make_engine(db_url)
    try:
        migrate(engine, "0001")
        with engine.begin() as conn:
            conn.execute(
                text("INSERT INTO blobs (sha256, size, data) VALUES ('ab', 1, :d)"), {"d": b"x"}
            )
            _program_and_audit_rows(conn)
        assert "received" not in set(inspect(engine).get_table_names())
        migrate(engine)
        assert current_revision(engine) == head_revision()
        assert "received" in set(inspect(engine).get_table_names())
        with engine.connect() as conn:
            assert conn.execute(text("SELECT name FROM programs")).scalars().all() == ["O1.nc"]
            assert conn.execute(text("SELECT actor FROM audit")).scalars().all() == ["ann"]
    finally:
        engine.dispose()


def test_upgrade_from_the_revision_before_head(db_url: str) -> None:
    # A shop running the schema just before this one: its library, audit trail and inbox come
    # along, the upgraded schema is the models' schema, and the server's code works on it.
    previous = ScriptDirectory(str(MIGRATIONS)).get_revision(head_revision()).down_revision
    assert isinstance(previous, str)
    engine = make_engine(db_url)
    try:
        migrate(engine, previous)
        assert current_revision(engine) == previous
        data = b"%\nO1\nM30\n%\n"
        digest = hashlib.sha256(data).hexdigest()
        with engine.begin() as conn:
            conn.execute(
                text("INSERT INTO blobs (sha256, size, data) VALUES (:h, :n, :d)"),
                {"h": digest, "n": len(data), "d": data},
            )
            _program_and_audit_rows(conn)
            conn.execute(
                text(
                    "INSERT INTO received (machine, name, sha256, size, state, reason, path, at) "
                    "VALUES ('vf2', 'O1.nc', :h, :n, 'new', '', 'inbox/O1.nc', CURRENT_TIMESTAMP)"
                ),
                {"h": digest, "n": len(data)},
            )
        migrate(engine)
        assert current_revision(engine) == head_revision()
        with engine.connect() as conn:
            assert _differences(conn) == []
        sessions = make_sessions(engine)
        with sessions.begin() as session:
            version, created = library.add_version(session, "O1.nc", data, author="bob")
            assert (created, version.number) == (True, 1)
        with sessions() as session:
            (item,) = inbox.list_received(session)
            assert (item.machine, inbox.content(session, item)) == ("vf2", data)
            actors = [r.actor for r in audit.query(session)]
            assert "ann" in actors
            assert "bob" in actors
    finally:
        engine.dispose()
