"""The deadlines every PostgreSQL connection carries, on the real PostgreSQL: the server-side
timeouts are set, a URL's own parameter wins, and a transaction that locked a lease row and
then went silent (its server cut off) is ended by PostgreSQL, so another server can take the
lease soon after."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from sqlalchemy import Engine, select, text
from sqlalchemy.exc import DBAPIError
from sqlalchemy.orm import Session, sessionmaker

from opendnc.server.machines.leases import Leases, holds
from opendnc.server.store.db import (
    IDLE_IN_TRANSACTION_MS,
    STATEMENT_TIMEOUT_MS,
    make_engine,
    make_sessions,
    migrate,
)
from opendnc.server.store.models import MachineLease
from tests.server.conftest import _pg_database
from tests.server.harness import wait_for


@pytest.fixture
def pg_url() -> Iterator[str]:
    yield from _pg_database()


@pytest.fixture
def pg(pg_url: str) -> Iterator[Engine]:
    engine = make_engine(pg_url)
    migrate(engine)
    yield engine
    engine.dispose()


def _shown(engine: Engine, name: str) -> str:
    with engine.connect() as connection:
        value = connection.execute(text(f"SHOW {name}")).scalar_one()
        return str(value)


def test_every_connection_has_the_server_side_timeouts(pg: Engine, pg_url: str) -> None:
    # PostgreSQL shows 60,000 ms as "1min"
    assert STATEMENT_TIMEOUT_MS == IDLE_IN_TRANSACTION_MS == 60_000
    assert _shown(pg, "statement_timeout") == "1min"
    assert _shown(pg, "idle_in_transaction_session_timeout") == "1min"
    # a URL that sets its own options keeps them
    own = make_engine(pg_url + "?options=-c%20statement_timeout%3D7000")
    try:
        assert _shown(own, "statement_timeout") == "7s"
    finally:
        own.dispose()


def test_a_silent_transaction_holding_a_lease_row_is_ended_by_the_database(
    pg: Engine,
) -> None:
    sessions: sessionmaker[Session] = make_sessions(pg)
    Leases(sessions, "dnc-1", {"m1": frozenset()}).renew()
    epoch = sessions().scalar(select(MachineLease.epoch).where(MachineLease.machine == "m1"))
    assert epoch is not None
    cut = sessions()
    try:
        cut.begin()
        # dnc-1 fences a job's end: the row is locked FOR SHARE, then dnc-1 goes silent
        assert holds(cut, "m1", "dnc-1", epoch, lock_limit=0.5)

        def lockable() -> bool:
            with pg.connect() as other:
                try:
                    other.execute(
                        select(MachineLease.machine)
                        .where(MachineLease.machine == "m1")
                        .with_for_update(nowait=True)
                    ).all()
                except DBAPIError:
                    other.rollback()
                    return False
                other.rollback()
                return True

        assert not lockable()  # held while the transaction lives
        wait_for("PostgreSQL to end the silent transaction", lockable, timeout=10)
        with pytest.raises(DBAPIError):
            cut.execute(text("SELECT 1"))
    finally:
        cut.close()


def test_a_connection_returned_after_its_engine_was_disposed_is_closed(pg_url: str) -> None:
    """Checked out, the engine disposed, handed back later: it goes to the old pool, which
    nothing uses; left open there it waits for the garbage collector (psycopg's "connection
    deleted while still open"). It is closed as it comes back."""
    engine = make_engine(pg_url)
    try:
        conn = engine.connect()
        conn.execute(text("SELECT 1"))
        raw = conn.connection.dbapi_connection
        assert raw is not None
        engine.dispose()  # the old pool is dropped with this connection out
        assert not raw.closed  # type: ignore[attr-defined]
        conn.close()
        assert raw.closed  # type: ignore[attr-defined]
        # a connection of the new pool is kept open on its return, as pools do
        with engine.connect() as fresh:
            kept = fresh.connection.dbapi_connection
        assert kept is not None
        assert not kept.closed  # type: ignore[attr-defined]
    finally:
        engine.dispose()
