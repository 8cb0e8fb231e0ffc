"""A server configured as the only one on PostgreSQL (``[server] cluster = false``) refuses to
start beside a live cluster server or another lone one, in one line, and starts once that
server is gone; a cluster server refuses beside a lone one. A lone server whose lock's
connection a blip ended takes the lock again."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from sqlalchemy import Engine, create_engine, text
from sqlalchemy.engine import make_url

from opendnc.server.app import build
from opendnc.server.cluster.single_server import (
    SERVER_LOCK_KEY,
    DatabaseInUse,
    ServerLock,
    refuse_beside_a_cluster,
)
from opendnc.server.config.shop import parse_config
from opendnc.server.machines.leases import Leases
from opendnc.server.store.db import DatabaseUnreachable, make_engine, make_sessions, migrate
from tests.server.conftest import PG_ADMIN, _pg_database
from tests.server.harness import wait_for
from tests.server.inprocess_app import config_text


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


def _backends_holding_the_lock(url: str) -> list[int]:
    admin = create_engine(PG_ADMIN, isolation_level="AUTOCOMMIT")
    try:
        with admin.connect() as conn:
            rows = conn.execute(
                text(
                    "SELECT l.pid FROM pg_locks l JOIN pg_database d ON d.oid = l.database "
                    "WHERE l.locktype = 'advisory' AND l.objid = :key AND d.datname = :name"
                ),
                {"key": SERVER_LOCK_KEY, "name": make_url(url).database},
            )
            return [int(r[0]) for r in rows]
    finally:
        admin.dispose()


def _end_sessions(pids: list[int]) -> None:
    admin = create_engine(PG_ADMIN, isolation_level="AUTOCOMMIT")
    try:
        with admin.connect() as conn:
            for pid in pids:
                conn.execute(text("SELECT pg_terminate_backend(:pid)"), {"pid": pid})
    finally:
        admin.dispose()


def test_two_lone_servers_or_a_lone_and_a_cluster_server_never_share_a_database(
    tmp_path: Path,
) -> None:
    # a lone server writes no heartbeat or lease: the lock is what the others see
    for url in _pg_database():
        machines = [{"name": "tnc", "kind": "lsv2", "host": "127.0.0.1", "port": 1}]
        lone = parse_config(
            "[server]\ncluster = false\n" + config_text(tmp_path, machines), base=tmp_path
        )
        clustered = parse_config(config_text(tmp_path, machines), base=tmp_path)
        first = build(lone, database=url)
        try:
            for config in (lone, clustered):
                with pytest.raises(DatabaseInUse) as refused:
                    build(config, database=url)
                assert "cluster = false" in str(refused.value)
                assert "\n" not in str(refused.value)
        finally:
            first.core.get(ServerLock).release()
            first.engine.dispose()
        # gone: cluster servers share the database, and a lone one is refused beside them
        one, two = build(clustered, database=url), build(clustered, database=url)
        try:
            with pytest.raises(DatabaseInUse):
                build(lone, database=url)
        finally:
            for server in (one, two):
                server.core.get(ServerLock).release()
                server.engine.dispose()


def test_a_lone_server_takes_its_lock_again_after_a_database_blip(
    pg: Engine, caplog: pytest.LogCaptureFixture
) -> None:
    url = pg.url.render_as_string(hide_password=False)
    lone = ServerLock(url, alone=True)
    lone.acquire()
    try:
        _end_sessions(_backends_holding_the_lock(url))  # the blip ends its session
        lone.check()  # sees it lost (and keeps driving: nothing here stops it)
        assert not lone.held
        assert "still driving every machine" in caplog.text
        lone.check()  # the database answers: it takes the lock again
        assert lone.held
        with pytest.raises(DatabaseInUse):
            ServerLock(url, alone=True).acquire()
        with pytest.raises(DatabaseInUse):
            ServerLock(url, alone=False).acquire()
    finally:
        lone.release()
    # the release closes the lock's connection; its backend ends a moment later (on a loaded
    # machine, later than the next line would ask)
    wait_for("the lock's session to end", lambda: _backends_holding_the_lock(url) == [], 10)


def test_a_database_that_refuses_the_locks_connection_is_one_line(pg: Engine) -> None:
    # Seen at -n 12: PostgreSQL out of connections between the migration and the lock; the
    # server ended with a traceback instead of the line every other refusal gets.
    url = pg.url.render_as_string(hide_password=False)
    name = make_url(url).database
    admin = create_engine(PG_ADMIN, isolation_level="AUTOCOMMIT")
    try:
        with admin.connect() as conn:
            conn.execute(text(f'ALTER DATABASE "{name}" ALLOW_CONNECTIONS false'))
        lock = ServerLock(url, alone=True)
        with pytest.raises(DatabaseUnreachable) as refused:
            lock.acquire()
        lock.release()
        message = str(refused.value)
        where = pg.url.render_as_string(hide_password=True)
        assert message.startswith(f"cannot reach the database {where}: "), message
        assert "not currently accepting connections" in message
        assert "\n" not in message
    finally:
        with admin.connect() as conn:
            conn.execute(text(f'ALTER DATABASE "{name}" ALLOW_CONNECTIONS true'))
        admin.dispose()
