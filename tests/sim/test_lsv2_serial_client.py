"""Serial LSV2 clients over a pty: the asyncio client, --baud auto and clear link errors."""

from __future__ import annotations

import asyncio
import os
import select
import threading
import tty
from pathlib import Path

import pytest
from typer.testing import CliRunner

from opendnc.cli.main import app
from opendnc.errors import TransferError, TransportError
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


class _NulEater:
    """A relay between the client's pty and the virtual TNC that loses the first NUL byte
    inside the first S_FL telegram of its direction: invisible to the XOR block check."""

    def __init__(self, sim_path: str, *, upstream: bool) -> None:
        self.client_side = open_pty()
        self.sim_fd = os.open(sim_path, os.O_RDWR | os.O_NOCTTY)
        tty.setraw(self.sim_fd)
        self.upstream = upstream
        self.eaten = False
        self.stop = False
        self.thread = threading.Thread(target=self.run, daemon=True)
        self.thread.start()

    def run(self) -> None:
        a, b = self.client_side.master_fd, self.sim_fd
        while not self.stop:
            ready, _, _ = select.select([a, b], [], [], 0.05)
            for fd in ready:
                data = os.read(fd, 4096)
                if (fd == a) == self.upstream and not self.eaten and b"S_FL" in data:
                    start = data.index(b"S_FL") + 4
                    nul = data.find(b"\0", start)
                    if nul > 0:
                        data = data[:nul] + data[nul + 1 :]
                        self.eaten = True
                os.write(b if fd == a else a, data)

    def close(self) -> None:
        self.stop = True
        self.thread.join(2)
        os.close(self.sim_fd)
        self.client_side.close()


@pytest.mark.parametrize("upstream", [True, False])
def test_a_lost_nul_is_caught_by_the_size_check(tmp_path: Path, upstream: bool) -> None:
    data = b"\x01" * 100 + b"\0" + b"\x02" * 100
    (tmp_path / "n.bin").write_bytes(data)
    with start_tnc("tnc640", root=tmp_path / "tnc") as tnc:
        front = attach_serial(tnc, "pty")
        if not upstream:  # put a clean copy there first
            with Client.over_serial(front.path) as client:
                client.upload(tmp_path / "n.bin", "TNC:/n.bin", binary=True)
        relay = _NulEater(front.path, upstream=upstream)

        def transfer(client: Client) -> None:
            if upstream:
                client.upload(tmp_path / "n.bin", "TNC:/n.bin", binary=True)
            else:
                client.download("TNC:/n.bin", tmp_path / "back.bin", binary=True)

        try:
            # The relay is a thread of this process: on a loaded machine it can hold a
            # telegram's BCC back past LSV2TIME2's 1 s, and the control's answer would be
            # refused on every repeat. The longest times allowed leave only the NUL to catch.
            slow = LinkTiming(time0=3.6, time1=3.6, time2=3.6)
            line = SerialLine(relay.client_side.slave_path, timing=slow)
            with (
                Client.over_serial(line) as client,
                pytest.raises(TransferError, match="let an error through"),
            ):
                transfer(client)
        finally:
            relay.close()
        assert relay.eaten
        if upstream:
            assert not (tnc.root / "TNC" / "n.bin").exists()
        else:
            assert not (tmp_path / "back.bin").exists()
