"""In a cluster the shop-wide duties (the library watcher, the net share) are components of
every server's core, and work on exactly one of them: the one whose cluster holds their lease
raises the duty flag. The cluster does not start them; the core does, and stops them."""

from __future__ import annotations

import asyncio
import time
from dataclasses import replace
from pathlib import Path

from opendnc.server.app import Server, build
from opendnc.server.cluster.single_server import ServerLock
from opendnc.server.config.shop import parse_config
from opendnc.server.core.components import Duty
from opendnc.server.library.watcher import LibraryWatcher
from tests.server.conftest import _pg_database
from tests.server.inprocess_app import config_text


def _duty(server: Server) -> Duty:
    found = [c for c in server.core.order() if isinstance(c, Duty)]
    assert [type(d.inner) for d in found] == [LibraryWatcher]
    assert server.core.get(LibraryWatcher) is found[0].inner  # found by its part's class
    return found[0]


async def _one_holds_the_duties(servers: list[Server], duties: list[Duty]) -> None:
    for server in servers:
        await server.core.start()
    try:
        deadline = time.monotonic() + 30
        while sum(d.working for d in duties) != 1:
            assert time.monotonic() < deadline, "no server took the duties"
            await asyncio.sleep(0.1)
        await asyncio.sleep(1.0)  # a few renewals more: still one, never two
        assert sum(d.working for d in duties) == 1
        holder = next(s for s, d in zip(servers, duties, strict=True) if d.working)
        cluster = holder.cluster
        assert cluster is not None
        assert cluster.duty.held
    finally:
        for server in servers:
            await server.core.stop()
    assert not any(d.working for d in duties)  # the core's stop ended the work


def test_one_server_of_two_runs_the_watcher_and_the_core_stops_it(tmp_path: Path) -> None:
    for url in _pg_database():
        machines = [{"name": "tnc", "kind": "lsv2", "host": "127.0.0.1", "port": 1}]
        config = parse_config(config_text(tmp_path, machines), base=tmp_path)
        servers = [
            build(replace(config, server=replace(config.server, name=name)), database=url)
            for name in ("dnc-1", "dnc-2")
        ]
        try:
            asyncio.run(_one_holds_the_duties(servers, [_duty(s) for s in servers]))
        finally:
            for server in servers:
                server.core.get(ServerLock).release()
                server.engine.dispose()
