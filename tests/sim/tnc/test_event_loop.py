"""Which event loop the virtual TNC runs on (uvloop when installed, asyncio on request)."""

from __future__ import annotations

import asyncio

import pytest

from opendnc.lsv2 import Client
from opendnc.sim.tnc import new_event_loop, start_tnc
from tests.peers import require_module


def test_forced_standard_loop(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("OPENDNC_SIM_LOOP", "asyncio")
    loop = new_event_loop()
    try:
        assert type(loop).__module__.startswith("asyncio")
    finally:
        loop.close()


def test_uvloop_when_installed(monkeypatch: pytest.MonkeyPatch) -> None:
    uvloop = require_module("uvloop")
    monkeypatch.delenv("OPENDNC_SIM_LOOP", raising=False)
    loop = new_event_loop()
    try:
        assert isinstance(loop, uvloop.Loop)
    finally:
        loop.close()


@pytest.mark.parametrize("forced", [True, False])
def test_transfer_on_either_loop(forced: bool, monkeypatch: pytest.MonkeyPatch) -> None:
    if forced:
        monkeypatch.setenv("OPENDNC_SIM_LOOP", "asyncio")
    else:
        monkeypatch.delenv("OPENDNC_SIM_LOOP", raising=False)
    data = bytes(range(256)) * 100  # several 4 KiB blocks each way
    with start_tnc() as tnc, Client("127.0.0.1", tnc.port, timeout=10) as client:
        module = tnc.call(lambda _c: type(asyncio.get_running_loop()).__module__)
        assert module.startswith("asyncio") or not forced
        client.write_file("TNC:\\loop.bin", data, binary=True)
        assert client.read_file("TNC:\\loop.bin", binary=True) == data
