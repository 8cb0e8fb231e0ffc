"""Engines, sessions and migrations for the server's database.

SQLite (the default, no set-up) and PostgreSQL (``postgresql+psycopg://``) take the same code.
SQLite gets write-ahead logging and a busy timeout so the web requests and the machine tasks of
one process can share the file; its foreign keys are switched on per connection because SQLite
leaves them off. Every SQLite transaction starts with ``BEGIN IMMEDIATE``: a transaction that
reads and then writes cannot take the write lock later if another connection committed in
between (SQLite answers "database is locked" at once, the busy timeout does not apply), so it
takes the lock first and waits for it instead.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from alembic import command
from alembic.config import Config
from alembic.runtime.migration import MigrationContext
from alembic.script import ScriptDirectory
from sqlalchemy import Engine, create_engine, event
from sqlalchemy.engine import make_url
from sqlalchemy.exc import ArgumentError
from sqlalchemy.orm import Session, sessionmaker

from opendnc.errors import InputError

__all__ = ["current_revision", "head_revision", "make_engine", "make_sessions", "migrate"]

MIGRATIONS = Path(__file__).with_name("migrations")


def make_engine(url: str) -> Engine:
    """An engine for ``url``; :class:`InputError` for a URL SQLAlchemy cannot use."""
    try:
        parsed = make_url(url)
    except ArgumentError as exc:
        raise InputError(f"not a database URL: {url!r}") from exc
    if parsed.get_backend_name() == "sqlite":
        database = parsed.database or ""
        if database and database != ":memory:":
            Path(database).parent.mkdir(parents=True, exist_ok=True)
        engine = create_engine(parsed, connect_args={"timeout": 30})
        event.listen(engine, "connect", _sqlite_pragmas)
        event.listen(engine, "begin", _sqlite_begin)
        return engine
    if parsed.get_backend_name() == "postgresql":
        return create_engine(parsed, pool_pre_ping=True)
    raise InputError(
        f"unsupported database {parsed.get_backend_name()!r}: use sqlite or postgresql"
    )


def _sqlite_pragmas(dbapi_connection: Any, _record: Any) -> None:
    # The driver's own transaction handling is off; _sqlite_begin starts every transaction.
    dbapi_connection.isolation_level = None
    cursor = dbapi_connection.cursor()
    cursor.execute("PRAGMA foreign_keys=ON")
    cursor.execute("PRAGMA journal_mode=WAL")
    cursor.execute("PRAGMA busy_timeout=30000")
    cursor.close()


def _sqlite_begin(connection: Any) -> None:
    connection.exec_driver_sql("BEGIN IMMEDIATE")


def make_sessions(engine: Engine) -> sessionmaker[Session]:
    """A session factory whose objects stay readable after commit."""
    return sessionmaker(engine, expire_on_commit=False)


def _alembic_config(connection: Any) -> Config:
    config = Config()
    config.set_main_option("script_location", str(MIGRATIONS))
    config.attributes["connection"] = connection
    return config


def migrate(engine: Engine, revision: str = "head") -> None:
    """Bring the schema to ``revision`` (upgrade or downgrade)."""
    with engine.begin() as connection:
        config = _alembic_config(connection)
        current = MigrationContext.configure(connection).get_current_revision()
        heads = ScriptDirectory.from_config(config)
        target = heads.get_current_head() if revision == "head" else revision
        if current == target:
            return
        if revision == "head" or _is_ancestor(heads, revision, current):
            command.upgrade(config, revision)
        else:
            command.downgrade(config, revision)


def _is_ancestor(scripts: ScriptDirectory, target: str, current: str | None) -> bool:
    # Upgrading from `current` reaches `target` when target lies above current in the history.
    if current is None:
        return True
    return any(rev.revision == current for rev in scripts.iterate_revisions(target, "base"))


def current_revision(engine: Engine) -> str | None:
    """The revision the database is at (None for an empty database)."""
    with engine.connect() as connection:
        return MigrationContext.configure(connection).get_current_revision()


def head_revision() -> str:
    """The newest revision this version of opendnc knows."""
    config = Config()
    config.set_main_option("script_location", str(MIGRATIONS))
    head = ScriptDirectory.from_config(config).get_current_head()
    assert head is not None  # the package ships at least one revision
    return head
