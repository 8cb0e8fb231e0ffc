"""``start_fleet(opcua=1, opcua_later=True)``, the demo's way: the OPC UA machine is listed at
once on the port its server will have, and :meth:`Fleet.start_opcua` builds and starts that
server in the background (its address space costs seconds of CPU)."""

from __future__ import annotations

import asyncio
import socket
from pathlib import Path

import pytest

from tests.peers import require_module

require_module("asyncua")

from opendnc.sim.fleet import server_config, start_fleet  # noqa: E402

DEADLINE = 60.0  # seconds the build may take on a loaded machine


def _listens(port: int) -> bool:
    try:
        socket.create_connection(("127.0.0.1", port), timeout=5).close()
    except OSError:
        return False
    return True


def test_the_opcua_machine_is_listed_at_once_and_its_server_built_later(tmp_path: Path) -> None:
    async def run() -> None:
        fleet = await start_fleet(tmp_path, tnc=0, haas=0, opcua=1, opcua_later=True)
        try:
            (machine,) = fleet.machines
            assert (machine.name, machine.kind, machine.device) == ("opc-1", "opcua", "opc-1")
            assert machine.port > 0
            assert f'endpoint = "opc.tcp://127.0.0.1:{machine.port}"' in server_config(fleet)
            # nothing built nor listening yet
            assert fleet.opcua is None
            assert fleet.opcua_started is None
            assert not _listens(machine.port)
            started = fleet.start_opcua()
            assert started is not None
            assert fleet.start_opcua() is started  # once
            await asyncio.wait_for(asyncio.shield(started), DEADLINE)
            assert fleet.opcua is not None
            assert fleet.opcua.url == f"opc.tcp://127.0.0.1:{machine.port}"
            assert list(fleet.machine_tools) == ["opc-1"]  # its scripted cycles run
            assert await asyncio.to_thread(_listens, machine.port)
        finally:
            await fleet.close()
        assert not _listens(machine.port)

    asyncio.run(run())


@pytest.mark.parametrize("start", [False, True], ids=["never-started", "closed-while-building"])
def test_a_fleet_closes_whatever_its_opcua_server_got_to(tmp_path: Path, start: bool) -> None:
    async def run() -> None:
        fleet = await start_fleet(tmp_path, tnc=0, haas=0, opcua=1, opcua_later=True)
        if start:
            fleet.start_opcua()
        await fleet.close()
        assert fleet.opcua is None
        assert fleet.opcua_started is None
        assert fleet.start_opcua() is None  # closed: nothing starts any more
        assert not _listens(fleet.machines[0].port)

    asyncio.run(run())
