"""The key that signs the browsers' device cookies lives in the database: a cookie one server
issued is known to a second server on the same PostgreSQL and to the first after a restart,
and to no server of another database (docs/server.md#throttling)."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from opendnc.server import actions
from opendnc.server.app import Server, build
from opendnc.server.cluster.single_server import ServerLock
from opendnc.server.config.shop import parse_config
from opendnc.server.store.db import make_engine, make_sessions, migrate
from opendnc.server.store.secrets import shared_secret
from tests.server.conftest import _pg_database
from tests.server.inprocess_app import config_text

MACHINES: list[dict[str, object]] = [
    {"name": "tnc", "kind": "lsv2", "host": "127.0.0.1", "port": 1},
]


def _done(server: Server) -> None:
    server.core.get(ServerLock).release()
    server.engine.dispose()


def test_a_device_cookie_is_good_on_every_server_of_the_database_and_after_a_restart(
    tmp_path: Path,
) -> None:
    config = parse_config(config_text(tmp_path, MACHINES), base=tmp_path)
    for url in _pg_database():
        one, two = build(config, database=url), build(config, database=url)
        try:
            cookie = one.core.get(actions.Services).guard.device_cookie(None, "ann")
            device = cookie.partition(":")[0]
            assert two.core.get(actions.Services).guard.device_of(cookie, "Ann") == device
            assert two.core.get(actions.Services).guard.device_of(cookie, "bob") is None
        finally:
            _done(one)
            _done(two)
        again = build(config, database=url)  # the first server, restarted
        try:
            assert again.core.get(actions.Services).guard.device_of(cookie, "ann") == device
        finally:
            _done(again)
    for other in _pg_database():  # another shop's database: another key
        elsewhere = build(config, database=other)
        try:
            assert elsewhere.core.get(actions.Services).guard.device_of(cookie, "ann") is None
        finally:
            _done(elsewhere)


def test_servers_starting_together_make_one_key() -> None:
    for url in _pg_database():
        engine = make_engine(url)
        try:
            migrate(engine)
            sessions = make_sessions(engine)
            with ThreadPoolExecutor(8) as pool:
                keys = set(pool.map(shared_secret, [sessions] * 8, ["k"] * 8))
            assert len(keys) == 1
            assert len(next(iter(keys))) == 32
        finally:
            engine.dispose()
