"""Fixtures for the server tests: every test that takes ``engine`` runs on SQLite and on the
machine's real PostgreSQL server (an empty database per test, see :class:`_Databases`)."""

from __future__ import annotations

import atexit
import contextlib
import os
import time
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.peers import missing_peer, require_module

require_module("sqlalchemy")
require_module("alembic")

from sqlalchemy import Engine, create_engine, text  # noqa: E402
from sqlalchemy.orm import Session, sessionmaker  # noqa: E402
from sqlalchemy.pool import NullPool  # noqa: E402

from opendnc.server.store.db import make_engine, make_sessions, migrate  # noqa: E402
from tests.server.harness import Procs  # noqa: E402

# The project's machines run PostgreSQL on 127.0.0.1:5432 with trust authentication.
PG_ADMIN = os.environ.get(
    "OPENDNC_TEST_PG", "postgresql+psycopg://postgres@127.0.0.1:5432/postgres"
)


class _Databases:
    """This worker's PostgreSQL databases for the tests: an empty one for each test, emptied
    again when the test ends and kept for the next one.

    Creating a database copies ``template1`` (7.5 MB) and cost the server 0.2-0.3 CPU s, for
    about 140 tests a run (measured); emptying one costs a hundredth of that. To this code
    base an emptied database is a fresh one: no schema but an empty ``public``, no database
    settings, connections allowed. (PostgreSQL itself still tells them apart, by statistics
    counters or a database comment, say; no test reads those.) It also gets a new name, so a
    process a test left behind cannot reach the next test's database by the name it knew. The
    databases are dropped when the worker exits."""

    def __init__(self) -> None:
        self._admin: Engine | None = None
        self._free: list[str] = []

    def admin(self) -> Engine:
        if self._admin is None:
            # not pooled: an idle connection a worker kept would be one fewer for the servers
            # (at -n 12, twelve of them ran PostgreSQL out of connections)
            self._admin = create_engine(PG_ADMIN, isolation_level="AUTOCOMMIT", poolclass=NullPool)
            atexit.register(self.drop_all)
        return self._admin

    def take(self) -> str:
        """The name of an empty database."""
        if self._free:
            return self._free.pop()
        name = _fresh_name()
        with self.admin().connect() as conn:
            conn.execute(text(f'CREATE DATABASE "{name}"'))
        return name

    def give_back(self, name: str) -> None:
        """Empty ``name`` for the next test (under a new name), or drop it if that fails."""
        renamed = _fresh_name()
        try:
            self._empty(name, renamed)
        except Exception:
            with self.admin().connect() as conn:
                for either in (name, renamed):
                    conn.execute(text(f'DROP DATABASE IF EXISTS "{either}" WITH (FORCE)'))
        else:
            self._free.append(renamed)

    def _empty(self, name: str, renamed: str) -> None:
        with self.admin().connect() as conn:
            # no new sessions, then none at all: a database in use cannot be renamed
            conn.execute(text(f'ALTER DATABASE "{name}" ALLOW_CONNECTIONS false'))
            end = time.monotonic() + 10
            while True:
                others = conn.execute(
                    text(
                        "SELECT count(pg_terminate_backend(pid)) FROM pg_stat_activity "
                        "WHERE datname = :name AND pid <> pg_backend_pid()"
                    ),
                    {"name": name},
                ).scalar_one()
                if not others:
                    break
                if time.monotonic() > end:
                    raise TimeoutError(f"sessions of {name} did not end")
                time.sleep(0.01)
            conn.execute(text(f'ALTER DATABASE "{name}" RENAME TO "{renamed}"'))
            conn.execute(text(f'ALTER DATABASE "{renamed}" RESET ALL'))
            conn.execute(text(f'ALTER DATABASE "{renamed}" CONNECTION LIMIT -1'))
            conn.execute(text(f'ALTER DATABASE "{renamed}" ALLOW_CONNECTIONS true'))
        inside = create_engine(_url_of(renamed), isolation_level="AUTOCOMMIT", poolclass=NullPool)
        try:
            with inside.connect() as conn:
                schemas = conn.execute(
                    text(
                        "SELECT nspname FROM pg_namespace WHERE nspname NOT LIKE 'pg\\_%' "
                        "AND nspname <> 'information_schema'"
                    )
                ).scalars()
                for schema in list(schemas):
                    conn.execute(text(f'DROP SCHEMA "{schema}" CASCADE'))
                # as CREATE DATABASE makes it on PostgreSQL 15 and later (before 15 this
                # fails, and the database is dropped instead: slower, not wrong)
                conn.execute(text("CREATE SCHEMA public AUTHORIZATION pg_database_owner"))
                conn.execute(text("GRANT USAGE ON SCHEMA public TO PUBLIC"))
        finally:
            inside.dispose()

    def drop_all(self) -> None:
        if self._admin is None:
            return
        with contextlib.suppress(Exception), self._admin.connect() as conn:
            for name in self._free:
                with contextlib.suppress(Exception):
                    conn.execute(text(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)'))
        self._free.clear()
        self._admin.dispose()


def _fresh_name() -> str:
    return f"opendnc_test_{uuid.uuid4().hex[:12]}"


def _url_of(name: str) -> str:
    return PG_ADMIN.rsplit("/", 1)[0] + f"/{name}"


_DATABASES = _Databases()


def _pg_database() -> Iterator[str]:
    """The URL of an empty PostgreSQL database for the test (see :class:`_Databases`)."""
    require_module("psycopg")
    try:
        name = _DATABASES.take()
    except Exception as exc:
        missing_peer(f"PostgreSQL at {PG_ADMIN} ({type(exc).__name__})")
    try:
        yield _url_of(name)
    finally:
        _DATABASES.give_back(name)


def on(backend: str) -> pytest.MarkDecorator:
    """Run a test that takes ``db_url`` on ``backend`` only ("sqlite" or "postgresql").

    The storage's own tests (the store, the queue, leases, a server killed mid-queue, the
    request load) run on both. A test whose subject is something else (a protocol through
    the server, a page, a command) runs on one: each backend carries about half of them, and
    the suite does not start a second fleet of processes to repeat the same transfer."""
    return pytest.mark.parametrize("db_url", [backend], indirect=True)


@pytest.fixture(params=["sqlite", "postgresql"])
def db_url(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[str]:
    """An empty database URL, on each backend."""
    if request.param == "sqlite":
        yield f"sqlite:///{tmp_path / 'opendnc.db'}"
    else:
        yield from _pg_database()


@pytest.fixture
def engine(db_url: str) -> Iterator[Engine]:
    """A migrated database."""
    engine = make_engine(db_url)
    migrate(engine)
    yield engine
    engine.dispose()


@pytest.fixture
def sessions(engine: Engine) -> sessionmaker[Session]:
    return make_sessions(engine)


@pytest.fixture
def procs(tmp_path: Path) -> Iterator[Procs]:
    """Child processes of the test, stopped at its end (logs under tmp_path/logs)."""
    logs = tmp_path / "logs"
    logs.mkdir()
    p = Procs(logs)
    try:
        yield p
    finally:
        p.stop_all()


@pytest.fixture
def shop(db_url: str, tmp_path: Path) -> Iterator[Any]:
    """One virtual TNC served by the server's components in this process, its connector
    gated (tests/server/inproc_server.py), and the way to cut the database (db_outage.py)."""
    from opendnc.server.app import build
    from opendnc.server.config.shop import MachineConfig, parse_config
    from opendnc.server.kinds.connector import Connector
    from opendnc.server.kinds.registry import connector_for
    from opendnc.server.library import versions as library
    from opendnc.sim.fleet import server_config
    from tests.server.db_outage import Outage
    from tests.server.harness import wait_for
    from tests.server.inproc_server import PROGRAM, Gated, Gates, Running, Shop
    from tests.server.test_from_the_control import FleetThread

    fleet = FleetThread(tmp_path / "machines", tnc=1, haas=0)
    outage = Outage(db_url)
    own = make_engine(db_url)  # the test's reads and writes, with the store's own deadlines
    gates = Gates()
    running = None
    try:
        text = server_config(fleet.fleet, poll_interval=0.2, library=tmp_path / "lib", check="warn")

        def gated(machine: MachineConfig) -> Connector:
            return Gated(connector_for(machine), gates)

        server = build(
            parse_config(text, base=tmp_path),
            database=db_url,
            connector_factory=gated,
            sweep_interval=0.3,
            retry_backoff=0.2,
        )
        outage.quicken(server.engine)
        with server.sessions.begin() as session:
            library.add_version(session, "O01234.nc", PROGRAM, author="test")
            library.release(session, "O01234.nc", 1, actor="test")
        running = Running(server)
        machine = fleet.fleet.machines[0]
        wait_for("the TNC online", lambda: server.machines.machines[machine.name].online)
        yield Shop(server, running, gates, outage, machine.root, machine.name, make_sessions(own))
    finally:
        outage.close()
        own.dispose()
        if running is not None:
            running.stop()
            running.server.engine.dispose()
        fleet.stop()
