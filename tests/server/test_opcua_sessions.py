"""One OPC UA session per server, shared by its machines (docs/opcua-input.md): machines of
one virtual server open one session and browse its machines folder once; each still sees its
own values; a server restart makes every machine on it reconnect to one new session; an
endpoint that refuses is tried once for all the machines that asked at the same time."""

from __future__ import annotations

import asyncio
import socket
from collections.abc import Iterator
from typing import Any

import pytest

from opendnc.errors import TransportError
from opendnc.server.kinds.opcua import session as sessions
from opendnc.server.kinds.opcua.connector import OpcuaConnector
from opendnc.server.kinds.opcua.schema import OpcuaMachine
from tests.server.opcua_support import ServerThread, server_thread

NAMES = ["lathe", "mill", "vmc"]


@pytest.fixture(scope="module")
def gateway() -> Iterator[ServerThread]:
    with server_thread(NAMES) as server:
        yield server


def _connector(url: str, name: str) -> OpcuaConnector:
    return OpcuaConnector(OpcuaMachine(name=name, endpoint=url, machine=name))


async def _until(what: str, check: Any, timeout: float = 10.0) -> None:
    """Poll ``check`` on the running loop until it holds (a deadline, not a sleep)."""
    deadline = asyncio.get_running_loop().time() + timeout
    while not check():
        if asyncio.get_running_loop().time() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        await asyncio.sleep(0.02)


def test_machines_of_one_server_share_one_session(gateway: ServerThread) -> None:
    for parts, name in enumerate(NAMES, start=1):
        gateway.step(name, lambda m, p=parts: m.power_on(parts=p * 10))

    async def scenario() -> None:
        connectors = [_connector(gateway.server.url, name) for name in NAMES]
        await asyncio.gather(*(c.connect() for c in connectors))
        pool = sessions.pool()
        assert pool.opened == 1
        assert len({id(c._session) for c in connectors}) == 1
        # each machine its own values, though one subscription carries them all
        want = {name: (i + 1) * 10 for i, name in enumerate(NAMES)}

        def counts() -> dict[str, int | None]:
            return {c.config.name: c.readings.parts for c in connectors}

        await _until(f"parts {want}", lambda: counts() == want)
        for c in connectors:
            assert (await c.status()).part_count == want[c.config.name]

        # a machine that leaves takes its items; the others stay on the session
        await connectors[0].close()
        assert pool.opened == 1
        assert connectors[1]._session is not None
        assert connectors[1]._session.users == 2

        # the server restarts: every machine sees the loss, and reconnects once, to one session
        await asyncio.to_thread(gateway.run, gateway.server.restart)

        async def lost(c: OpcuaConnector) -> bool:
            try:
                await c.status()
            except TransportError:
                return True
            return False

        for c in connectors[1:]:
            deadline = asyncio.get_running_loop().time() + 10
            while not await lost(c):
                assert asyncio.get_running_loop().time() < deadline, "the loss was not seen"
                await asyncio.sleep(0.02)
        for c in connectors[1:]:
            await c.close()
        await asyncio.gather(*(c.connect() for c in connectors))
        assert pool.opened == 2
        assert all(c.sessions == 2 for c in connectors[1:])
        await _until(f"parts {want} again", lambda: counts() == want)
        for c in connectors:
            await c.close()
        assert not pool.sessions

    asyncio.run(scenario())


def test_a_refused_endpoint_is_tried_once_for_the_machines_waiting(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    with socket.socket() as probe:  # a port nobody listens on
        probe.bind(("127.0.0.1", 0))
        url = f"opc.tcp://127.0.0.1:{probe.getsockname()[1]}"
    opened = 0
    real = sessions._open

    async def counting(key: sessions.SessionKey, config: OpcuaMachine) -> sessions.Session:
        nonlocal opened
        opened += 1
        return await real(key, config)

    monkeypatch.setattr(sessions, "_open", counting)

    async def scenario() -> None:
        connectors = [_connector(url, f"m{i}") for i in range(6)]
        found = await asyncio.gather(*(c.connect() for c in connectors), return_exceptions=True)
        assert all(isinstance(e, TransportError) for e in found), found
        assert opened == 1
        # a later attempt is a new attempt
        with pytest.raises(TransportError):
            await connectors[0].connect()
        assert opened == 2

    asyncio.run(scenario())
