"""The asyncio AsyncClient over real TCP against the virtual TNC (same ops as Client)."""

from __future__ import annotations

import asyncio
import os
from collections.abc import Coroutine
from pathlib import Path
from typing import Any

import pytest

from opendnc.errors import ControlRefused, PeerClosed, SafetyLockError, TransportError
from opendnc.lsv2 import AsyncClient, ExecutionMode, Family, KeyCode, ProgramState
from opendnc.sim.tnc import TncHandle, serve_tnc, start_tnc
from tests.sim.lsv2_fixtures import itnc530, pinned_state, tnc640

__all__ = ["itnc530", "tnc640"]


def arun(coro: Coroutine[Any, Any, None]) -> None:
    asyncio.run(asyncio.wait_for(coro, 30))


def test_session_files_and_state(tnc640: TncHandle, tmp_path: Path) -> None:
    data = os.urandom(50_000)
    (tmp_path / "up.bin").write_bytes(data)

    async def scenario() -> None:
        async with AsyncClient("127.0.0.1", tnc640.port, timeout=5) as c:
            assert c.family is Family.TNC_NEW
            assert c.buffer_size == 4096
            assert await c.make_dir("TNC:/aio/sub")
            assert await c.upload(tmp_path / "up.bin", "TNC:/aio/sub/") == len(data)
            listing = await c.list_dir("TNC:/aio/sub")
            assert [(e.name, e.size) for e in listing] == [("up.bin", len(data))]
            assert await c.download("TNC:/aio/sub/up.bin", tmp_path / "down.bin") == len(data)
            assert (tmp_path / "down.bin").read_bytes() == data
            await c.delete_file("TNC:/aio/sub/up.bin")
            await c.remove_dir("TNC:/aio/sub")
            await c.remove_dir("TNC:/aio")
            with pinned_state(tnc640, ProgramState.ERROR, ExecutionMode.MDI):
                assert await c.program_state() is ProgramState.ERROR
                assert await c.execution_mode() is ExecutionMode.MDI
            assert await c.read_plc("S0") == ["STRING 0"]
            with pytest.raises(SafetyLockError):
                await c.send_key(KeyCode.MODE_MANUAL)
            with pytest.raises(ControlRefused) as err:
                await c.read_file("TNC:/nothing.h")
            assert err.value.code == 32

    arun(scenario())


def test_concurrent_calls_are_serialised(tnc640: TncHandle) -> None:
    async def scenario() -> None:
        async with AsyncClient("127.0.0.1", tnc640.port, safe_mode=False) as c:
            results = await asyncio.gather(
                *(c.read_plc(f"M{i}") for i in range(20)),
                c.execution_mode(),
                c.list_dir("TNC:/"),
                c.overrides(),
            )
            assert len(results) == 23
            await c.send_key(KeyCode.MODE_MANUAL)
            assert await c.execution_mode() is ExecutionMode.MANUAL

    arun(scenario())


def test_itnc_nc_errors_and_scope(itnc530: TncHandle) -> None:
    async def scenario() -> None:
        async with AsyncClient("127.0.0.1", itnc530.port) as c:
            itnc530.call(lambda ctl: ctl.machine.raise_error("ASYNC ERROR"))
            errors = await c.nc_errors()
            assert errors[-1].text == "ASYNC ERROR"
            itnc530.call(lambda ctl: ctl.machine.clear_errors())
            channels = await c.scope_channels()
            assert channels

    arun(scenario())


def test_server_in_same_loop_and_peer_closed(tmp_path: Path) -> None:
    async def scenario() -> None:
        server = await serve_tnc("tnc640", tmp_path, port=0)
        c = AsyncClient("127.0.0.1", server.port, timeout=5)
        await c.connect()
        assert (await c.read_versions()).model == "TNC640"
        await server.close()
        with pytest.raises((PeerClosed, TransportError)):
            await c.list_dir("TNC:/")
        await c.close()

    arun(scenario())


def test_cancelled_call_marks_link_out_of_step() -> None:
    async def scenario() -> None:
        with start_tnc("tnc640", latency=0.2) as tnc:
            async with AsyncClient("127.0.0.1", tnc.port, max_buffer=256, secure_send=False) as c:
                task = asyncio.create_task(c.program_state())
                await asyncio.sleep(0.05)
                task.cancel()
                with pytest.raises(asyncio.CancelledError):
                    await task
                with pytest.raises(TransportError, match="reconnect"):
                    await c.program_state()

    arun(scenario())
