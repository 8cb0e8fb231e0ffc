"""MDC over real TCP sockets against the virtual Haas (NGC and classic framing)."""

from __future__ import annotations

import asyncio
import re
import socket
import time
from pathlib import Path

import pytest

from opendnc.errors import ControlRefused, InputError, SafetyLockError
from opendnc.haas import mdc
from opendnc.haas.mdc_client import AsyncMdcClient, MdcClient, macro_set_op
from opendnc.sim.haas import HaasConfig, SimHaasThread, SimOptions

# Reply payload formats of Haas's table (docs/haas.md#q-commands)
FORMATS = {
    "?Q100": r"SERIAL NUMBER, \S+",
    "?Q101": r"SOFTWARE VERSION, \S+",
    "?Q102": r"MODEL, VF-2",
    "?Q104": r"MODE, (MDI|\(MDI\))",
    "?Q200": r"TOOL CHANGES, \d+",
    "?Q201": r"USING TOOL, \d+",
    "?Q300": r"P\.O\. TIME, \d{5}:\d{2}:\d{2}",
    "?Q301": r"C\.S\. TIME, \d{5}:\d{2}:\d{2}",
    "?Q303": r"LAST CYCLE, \d{5}:\d{2}:\d{2}",
    "?Q304": r"PREV CYCLE, \d{5}:\d{2}:\d{2}",
    "?Q402": r"M30 #1, \d+",
    "?Q403": r"M30 #2, \d+",
    "?Q500": r"PROGRAM, MDI, IDLE, PARTS, \d+",
    "?Q600 5223": r"MACRO, -?\d+\.\d+",
}


def framed(payload_regex: str, control: mdc.ControlType) -> bytes:
    if control is mdc.ControlType.NGC:
        return (">" + payload_regex + "\r\n").encode()
    return ("\x02" + payload_regex + "\x17\r\n>").encode()


def recv_exact_reply(sock: socket.socket, control: mdc.ControlType) -> bytes:
    end = b"\r\n" if control is mdc.ControlType.NGC else b"\r\n>"
    data = b""
    while not data.endswith(end):
        chunk = sock.recv(4096)
        assert chunk, "control closed the connection"
        data += chunk
    return data


def test_every_q_command_raw_bytes(sim: SimHaasThread, control_type: mdc.ControlType) -> None:
    assert sim.sim is not None
    assert sim.sim.mdc is not None
    with socket.create_connection(("127.0.0.1", sim.sim.mdc.port), timeout=3) as sock:
        for command, payload in FORMATS.items():
            sock.sendall(command.encode() + b"\r\n")
            reply = recv_exact_reply(sock, control_type)
            assert re.fullmatch(framed(payload, control_type), reply), (command, reply)
        unknown = "UNKNOWN" if control_type is mdc.ControlType.CLASSIC else "?"
        for bad in (b"?q100", b"?Q999", b"HELLO"):
            sock.sendall(bad + b"\n")
            assert recv_exact_reply(sock, control_type) == mdc.frame_reply(unknown, control_type)


def wait_for_sessions(sim: SimHaasThread, count: int) -> None:
    """The server registers a connection a moment after the kernel accepted it."""
    assert sim.sim is not None
    assert sim.sim.mdc is not None
    mdc_server = sim.sim.mdc
    deadline = time.monotonic() + 3
    while sim.call(lambda: len(mdc_server.writers)) != count:
        assert time.monotonic() < deadline, "server did not register the connections"
        time.sleep(0.01)


def test_client_queries_and_status(sim: SimHaasThread, control_type: mdc.ControlType) -> None:
    assert sim.sim is not None
    assert sim.sim.mdc is not None
    with MdcClient("127.0.0.1", sim.sim.mdc.port) as client:
        assert client.query(100) == mdc.TextValue("SERIAL NUMBER", "1234567")
        assert client.query(500) == mdc.ProgramStatus("MDI", "IDLE", 0)
        sim.call(lambda: sim.sim.control.start_program(321))  # type: ignore[union-attr]
        deadline = time.monotonic() + 3
        while isinstance(status := client.query(500), mdc.Busy) and time.monotonic() < deadline:
            time.sleep(0.01)
        assert status == mdc.ProgramStatus("O00321", "IDLE", 1)
        summary = client.status()
        assert summary.tool == 2
        assert summary.tool_changes == 1
        assert summary.m30_counter_1 == 1
        assert summary.mode == "MEM"
        assert client.macro_get(5223) == pytest.approx(-1.25 + 0.02 * 1.5)


def test_macro_set_then_get(sim: SimHaasThread) -> None:
    assert sim.sim is not None
    assert sim.sim.mdc is not None
    with MdcClient("127.0.0.1", sim.sim.mdc.port) as client:
        with pytest.raises(SafetyLockError):
            client.macro_set(10100, 1.5)
        assert client.macro_get(10100) == 0.0
        client.safe_mode = False
        client.macro_set(10100, 1.5)
        assert client.macro_get(10100) == 1.5
        with pytest.raises(SafetyLockError, match="general-purpose"):
            client.macro_set(5223, 1.0)  # a work offset: not on the default allow-list
        client.allow_any_variable = True
        client.macro_set(5223, -0.5)
        assert client.macro_get(5223) == -0.5
        with pytest.raises(InputError, match="read-only"):
            client.macro_set(5021, 1.0)  # machine position: refused before it is sent ...
        with pytest.raises(ControlRefused):
            client.run(macro_set_op(5021, 1.0))  # ... and by the control if sent anyway (?)


def test_two_connections_and_broadcast(sim: SimHaasThread) -> None:
    assert sim.sim is not None
    assert sim.sim.mdc is not None
    port = sim.sim.mdc.port
    with (
        socket.create_connection(("127.0.0.1", port), timeout=3) as first,
        socket.create_connection(("127.0.0.1", port), timeout=3) as second,
    ):
        wait_for_sessions(sim, 2)
        first.sendall(b"?Q102\r\n")
        # both connections get the reply to the first one's request
        expected = mdc.frame_reply("MODEL, VF-2", sim.sim.control.control_type)
        assert recv_exact_reply(first, sim.sim.control.control_type) == expected
        assert recv_exact_reply(second, sim.sim.control.control_type) == expected
        with socket.create_connection(("127.0.0.1", port), timeout=3) as third:
            assert third.recv(100) == b""  # a third connection is closed at once
        assert sim.sim.mdc.refused == 1
    wait_for_sessions(sim, 0)
    # once one closes, a new client is accepted again
    with MdcClient("127.0.0.1", port) as client:
        assert client.query(102) == mdc.TextValue("MODEL", "VF-2")


def test_async_client(sim: SimHaasThread) -> None:
    assert sim.sim is not None
    assert sim.sim.mdc is not None
    port = sim.sim.mdc.port

    async def main() -> tuple[mdc.Reply, float, str | None]:
        async with await AsyncMdcClient.connect("127.0.0.1", port, safe_mode=False) as client:
            reply = await client.query(101)
            await client.macro_set(500, -3.25)
            value = await client.macro_get(500)
            status = await client.status()
            return reply, value, status.model

    reply, value, model = asyncio.run(main())
    assert isinstance(reply, mdc.TextValue)
    assert value == -3.25
    assert model == "VF-2"


def test_client_resends_a_first_query_the_control_ignored(tmp_path: Path) -> None:
    config = HaasConfig(ignore_first_query=True)
    with SimHaasThread(config, tmp_path, SimOptions(mdc_port=0)) as thread:
        assert thread.sim is not None
        assert thread.sim.mdc is not None
        with MdcClient("127.0.0.1", thread.sim.mdc.port, timeout=0.3) as client:
            assert client.query(100) == mdc.TextValue("SERIAL NUMBER", "1234567")
            assert client.query(102) == mdc.TextValue("MODEL", "VF-2")
