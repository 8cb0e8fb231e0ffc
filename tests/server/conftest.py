"""Fixtures for the server tests: every test that takes ``engine`` runs on SQLite and on the
machine's real PostgreSQL server (a fresh database per test, dropped afterwards)."""

from __future__ import annotations

import os
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

from opendnc.server.store.db import make_engine, make_sessions, migrate  # noqa: E402
from tests.server.harness import Procs  # noqa: E402

# The project's machines run PostgreSQL on 127.0.0.1:5432 with trust authentication.
PG_ADMIN = os.environ.get(
    "OPENDNC_TEST_PG", "postgresql+psycopg://postgres@127.0.0.1:5432/postgres"
)


def _pg_database() -> Iterator[str]:
    require_module("psycopg")
    admin = create_engine(PG_ADMIN, isolation_level="AUTOCOMMIT")
    name = f"opendnc_test_{uuid.uuid4().hex[:12]}"
    try:
        with admin.connect() as conn:
            conn.execute(text(f'CREATE DATABASE "{name}"'))
    except Exception as exc:
        admin.dispose()
        missing_peer(f"PostgreSQL at {PG_ADMIN} ({type(exc).__name__})")
    try:
        yield PG_ADMIN.rsplit("/", 1)[0] + f"/{name}"
    finally:
        with admin.connect() as conn:
            conn.execute(text(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)'))
        admin.dispose()


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
