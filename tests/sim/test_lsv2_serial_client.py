"""Serial LSV2 clients over a pty: the asyncio client, --baud auto and clear link errors."""

from __future__ import annotations

import asyncio
import os
from pathlib import Path

import pytest
from typer.testing import CliRunner

from opendnc.cli.main import app
from opendnc.errors import TransportError
from opendnc.lsv2 import AsyncClient, Client
from opendnc.lsv2.serial_link import HostStatus, LinkTiming, SerialLinkError
from opendnc.lsv2.serial_stream import SerialLine, probe_baud
from opendnc.sim.tnc import start_tnc
from opendnc.sim.tnc.serial_front import attach_serial
from opendnc.transport.pty import open_pty

runner = CliRunner()


def test_async_client_over_serial(tmp_path: Path) -> None:
    data = os.urandom(5000) + b"\x10" * 300
    (tmp_path / "a.bin").write_bytes(data)

    async def main(path: str) -> tuple[str, list[str]]:
        async with AsyncClient.over_serial(path, max_buffer=512) as tnc:
            await tnc.upload(tmp_path / "a.bin", "TNC:/a.bin", binary=True)
            await tnc.download("TNC:/a.bin", tmp_path / "b.bin", binary=True)
            names = [e.name for e in await tnc.list_dir("TNC:/")]
            return tnc.versions.model, names

    with start_tnc("tnc640", root=tmp_path / "tnc") as tnc:
        front = attach_serial(tnc, "pty")
        model, names = asyncio.run(main(front.path))
    assert model == tnc.profile.model
    assert "a.bin" in names
    assert (tmp_path / "b.bin").read_bytes() == data


def test_baud_auto_reports_the_rate_and_works(tmp_path: Path) -> None:
    with start_tnc("tnc320", root=tmp_path) as tnc:
        front = attach_serial(tnc, "pty")
        assert probe_baud(SerialLine(front.path, None)) == 57600
        result = runner.invoke(app, ["lsv2", "--serial", front.path, "--baud", "auto", "info"])
        assert result.exit_code == 0, (result.stdout, result.stderr)
        assert "answered at 57600 baud" in result.stderr
        assert "TNC320" in result.stdout


def test_silent_line_is_a_clear_no_enq_error() -> None:
    pty = open_pty()  # nobody answers on the other end
    try:
        line = SerialLine(pty.slave_path, timing=LinkTiming(time1=0.2), retries=1)
        with pytest.raises(SerialLinkError) as info:
            Client.over_serial(line, timeout=2).connect()
        assert info.value.status is HostStatus.NO_ENQ
        assert isinstance(info.value, TransportError)
        result = runner.invoke(
            app, ["lsv2", "--serial", pty.slave_path, "--baud", "nonsense", "info"]
        )
        assert result.exit_code == 1
        assert "bad --baud" in result.stderr
    finally:
        pty.close()
