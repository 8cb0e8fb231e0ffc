"""A server configured as the only one on PostgreSQL (``[server] cluster = false``) refuses to
start beside a live cluster server, in one line, and starts once that server is gone."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from sqlalchemy import Engine

from opendnc.server.leases import Leases
from opendnc.server.single_server import DatabaseInUse, refuse_beside_a_cluster
from opendnc.server.store.db import make_engine, make_sessions, migrate
from tests.server.conftest import _pg_database


@pytest.fixture
def pg() -> Iterator[Engine]:
    for url in _pg_database():
        engine = make_engine(url)
        migrate(engine)
        yield engine
        engine.dispose()


def test_a_lone_server_refuses_to_start_beside_a_live_cluster_server(pg: Engine) -> None:
    sessions = make_sessions(pg)
    refuse_beside_a_cluster(sessions, "alone")  # nobody else: it may start
    other = Leases(sessions, "dnc-1", {"m1": frozenset()})
    other.renew()  # a live cluster server holding a machine
    with pytest.raises(DatabaseInUse) as refused:
        refuse_beside_a_cluster(sessions, "alone")
    message = str(refused.value)
    assert "dnc-1" in message
    assert "cluster = false" in message
    assert "\n" not in message
    other.release_all()  # a clean stop: gone from the database at once
    refuse_beside_a_cluster(sessions, "alone")
