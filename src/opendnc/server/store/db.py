"""Engines, sessions and migrations for the server's database.

SQLite (the default, no set-up) and PostgreSQL (``postgresql+psycopg://``) take the same code.
SQLite gets write-ahead logging and a busy timeout so the web requests and the machine tasks of
one process can share the file; its foreign keys are switched on per connection because SQLite
leaves them off. Every SQLite transaction starts with ``BEGIN IMMEDIATE``: a transaction that
reads and then writes cannot take the write lock later if another connection committed in
between (SQLite answers "database is locked" at once, the busy timeout does not apply), so it
takes the lock first and waits for it instead. Sessions made with ``read_only`` (reads that
never commit: the dashboard's pages and live cards, the job sweep) start with a plain
``BEGIN`` instead: under write-ahead logging they read the last committed state without
waiting for the write lock, so a burst of job claims does not hold the live views back
(docs/server.md#event-loop-stalls).

Every PostgreSQL connection gets deadlines (:func:`pg_connect_args`): a connect timeout, TCP
keepalives and a TCP user timeout (a network that drops packets breaks the connection instead of
leaving a call blocked for ever), and server-side statement and idle-in-transaction timeouts (a
transaction whose client went silent gives its row locks back: a cut-off server's lease rows
must not stay locked). docs/server.md#database-deadlines.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from alembic import command
from alembic.config import Config
from alembic.runtime.migration import MigrationContext
from alembic.script import ScriptDirectory
from sqlalchemy import Connection, Engine, create_engine, event
from sqlalchemy.engine import make_url
from sqlalchemy.exc import ArgumentError, DBAPIError
from sqlalchemy.orm import Session, sessionmaker

from opendnc.errors import InputError, TransportError, os_reason

__all__ = [
    "READ_ONLY",
    "DatabaseUnreachable",
    "connect",
    "current_revision",
    "head_revision",
    "make_engine",
    "make_sessions",
    "migrate",
    "pg_connect_args",
    "read_only",
]

MIGRATIONS = Path(__file__).with_name("migrations")
READ_ONLY = "opendnc_read_only"  # execution option of the sessions that only read

# The most connections the pool holds: one for each worker thread that can hold a session at
# the same moment (the web requests' 40, AnyIO's default, and the machine tasks' asyncio
# executor, min(32, CPUs + 4)), so a thread never waits for a connection while the threads
# that hold the connections wait for something else (docs/server.md#database-sessions). They
# are opened as needed and then kept: a pool that kept only a few closed and reopened the rest
# under load, and opening one (SQLite's pragmas, a PostgreSQL backend) cost more than the
# query it was opened for. A small overflow covers threads outside those two pools.
POOL_SIZE = 40 + min(32, (os.cpu_count() or 1) + 4) + 2
MAX_OVERFLOW = 8

# Deadlines of every PostgreSQL connection (docs/server.md#database-deadlines). Generous for a
# single statement (a utilization sum over months), short for the network: a connection that
# cannot be opened in 5 s, or whose sent data stays unacknowledged for 15 s, is given up.
CONNECT_TIMEOUT_S = 5
KEEPALIVE_IDLE_S = 10  # a quiet connection is probed after this
KEEPALIVE_INTERVAL_S = 3  # then every this
KEEPALIVE_COUNT = 3  # and declared dead after this many unanswered probes
TCP_USER_TIMEOUT_MS = 15_000  # sent bytes unacknowledged this long: the connection is dead
STATEMENT_TIMEOUT_MS = 60_000
IDLE_IN_TRANSACTION_MS = 60_000


def make_engine(url: str) -> Engine:
    """An engine for ``url``; :class:`InputError` for a URL SQLAlchemy cannot use."""
    try:
        parsed = make_url(url)
    except ArgumentError as exc:
        raise InputError(f"not a database URL: {url!r}") from exc
    if parsed.get_backend_name() == "sqlite":
        database = parsed.database or ""
        if database and database != ":memory:":
            try:
                Path(database).parent.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise DatabaseUnreachable(
                    f"cannot make the database's folder {Path(database).parent}: {os_reason(exc)}"
                ) from None
        engine = create_engine(
            parsed, connect_args={"timeout": 30}, pool_size=POOL_SIZE, max_overflow=MAX_OVERFLOW
        )
        event.listen(engine, "connect", _sqlite_pragmas)
        event.listen(engine, "begin", _sqlite_begin)
        _close_returns_to_disposed_pools(engine)
        return engine
    if parsed.get_backend_name() == "postgresql":
        engine = create_engine(
            parsed,
            pool_pre_ping=True,
            pool_size=POOL_SIZE,
            max_overflow=MAX_OVERFLOW,
            connect_args=pg_connect_args(dict(parsed.query)),
        )
        _close_returns_to_disposed_pools(engine)
        return engine
    raise InputError(
        f"unsupported database {parsed.get_backend_name()!r}: use sqlite or postgresql"
    )


_POOL_KEY = "opendnc_pool"  # the id of the pool a connection was checked out of


def _close_returns_to_disposed_pools(engine: Engine) -> None:
    """A connection checked out while its engine was disposed goes back, later, to the old
    pool, which nothing uses any more: it would stay open there until the garbage collector
    finds it (psycopg then warns "connection deleted while still open"). It is closed as it
    comes back instead."""

    def checkout(_dbapi: Any, record: Any, _proxy: Any) -> None:
        record.info[_POOL_KEY] = id(engine.pool)

    def checkin(dbapi: Any, record: Any) -> None:
        if dbapi is not None and record.info.get(_POOL_KEY, id(engine.pool)) != id(engine.pool):
            with contextlib.suppress(Exception):  # closing a broken connection may fail
                dbapi.close()

    event.listen(engine, "checkout", checkout)
    event.listen(engine, "checkin", checkin)


def pg_connect_args(given: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """libpq's connection parameters for the deadlines above, leaving out any the database URL
    sets itself (``given``: its query parameters), which win."""
    given = given or {}
    options = (
        f"-c statement_timeout={STATEMENT_TIMEOUT_MS} "
        f"-c idle_in_transaction_session_timeout={IDLE_IN_TRANSACTION_MS}"
    )
    wanted: dict[str, Any] = {
        "connect_timeout": CONNECT_TIMEOUT_S,
        "keepalives": 1,
        "keepalives_idle": KEEPALIVE_IDLE_S,
        "keepalives_interval": KEEPALIVE_INTERVAL_S,
        "keepalives_count": KEEPALIVE_COUNT,
        "tcp_user_timeout": TCP_USER_TIMEOUT_MS,
        "options": options,
    }
    return {k: v for k, v in wanted.items() if k not in given}


def _sqlite_pragmas(dbapi_connection: Any, _record: Any) -> None:
    # The driver's own transaction handling is off; _sqlite_begin starts every transaction.
    dbapi_connection.isolation_level = None
    cursor = dbapi_connection.cursor()
    cursor.execute("PRAGMA foreign_keys=ON")
    cursor.execute("PRAGMA journal_mode=WAL")
    cursor.execute("PRAGMA busy_timeout=30000")
    cursor.close()


def _sqlite_begin(connection: Any) -> None:
    if connection.get_execution_options().get(READ_ONLY):
        connection.exec_driver_sql("BEGIN")  # a snapshot; never takes the write lock
    else:
        connection.exec_driver_sql("BEGIN IMMEDIATE")


def make_sessions(engine: Engine, *, reads_only: bool = False) -> sessionmaker[Session]:
    """A session factory whose objects stay readable after commit.

    ``reads_only``: for sessions that read and never commit; on SQLite they do not wait for
    the write lock (see the module docstring). A write in one is not what they are for: it
    may fail at once with "database is locked" where a writing session would have waited.
    """
    options = {READ_ONLY: True} if reads_only else {}
    return sessionmaker(engine, expire_on_commit=False, execution_options=options)


def read_only(sessions: sessionmaker[Session]) -> sessionmaker[Session]:
    """A factory like ``sessions`` (same engine) whose sessions only read."""
    engine = sessions.kw["bind"]
    if not isinstance(engine, Engine):
        raise InputError("the session factory is not bound to an engine")
    return make_sessions(engine, reads_only=True)


def _alembic_config(connection: Any) -> Config:
    config = Config()
    config.set_main_option("script_location", str(MIGRATIONS))
    config.attributes["connection"] = connection
    return config


class DatabaseUnreachable(TransportError):
    """The database could not be connected to (down, refusing, a file that cannot be opened)."""


def reason_of(exc: DBAPIError) -> str:
    """The driver's first line about ``exc``, without SQLAlchemy's decoration, lower case."""
    text = str(exc.orig).strip().splitlines()[0] if str(exc.orig).strip() else type(exc).__name__
    return text[:1].lower() + text[1:]


def unreachable(engine: Engine, exc: DBAPIError) -> DatabaseUnreachable:
    """The one-line error for ``engine``'s failed connection ``exc``."""
    where = engine.url.render_as_string(hide_password=True)
    return DatabaseUnreachable(f"cannot reach the database {where}: {reason_of(exc)}")


def connect(engine: Engine) -> Connection:
    """A connection of ``engine``; :class:`DatabaseUnreachable` in one line if none opens."""
    try:
        return engine.connect()
    except DBAPIError as exc:
        raise unreachable(engine, exc) from None


def migrate(engine: Engine, revision: str = "head") -> None:
    """Bring the schema to ``revision`` (upgrade or downgrade); :class:`DatabaseUnreachable`
    when the database cannot be reached."""
    with connect(engine) as connection, connection.begin():
        if connection.dialect.name == "postgresql":
            # a migration may rewrite a large table: no statement deadline for it
            connection.exec_driver_sql("SET LOCAL statement_timeout = 0")
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
