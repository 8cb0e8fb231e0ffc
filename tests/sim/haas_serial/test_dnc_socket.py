"""The blocking drip-feed through a serial device server: ``socket://HOST:PORT``.

socat plays the device server in raw TCP mode: it listens on loopback and carries the bytes to
the PC end of the virtual cable, whose other end is the virtual Haas. The PC side opens the
address with the dispatcher, which gives ``socket://`` the TCP stream.
"""

from __future__ import annotations

import select
import socket
import subprocess
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from opendnc.haas.dnc import DncConfig, stream_program
from opendnc.sim.haas.dnc_link import DncLimits
from opendnc.sim.haas.serial_front import SerialOptions, parse_mode
from tests.peers import require_command

from .conftest import Bench
from .test_dnc_serial import write_program


@pytest.fixture
def device_server() -> Iterator[Callable[[str], int]]:
    """Start socat between a loopback TCP port and a device; returns the port."""
    procs: list[subprocess.Popen[str]] = []

    def start(device: str) -> int:
        socat = require_command("socat")
        with socket.create_server(("127.0.0.1", 0)) as probe:
            port = int(probe.getsockname()[1])
        proc = subprocess.Popen(
            [
                socat,
                "-d",
                "-d",
                f"TCP-LISTEN:{port},bind=127.0.0.1,reuseaddr",
                f"FILE:{device},raw,echo=0",
            ],
            stderr=subprocess.PIPE,
            text=True,
        )
        procs.append(proc)
        assert proc.stderr is not None
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            if select.select([proc.stderr], [], [], 0.1)[0]:
                line = proc.stderr.readline()
                if "listening on" in line:
                    return port
                assert line, "socat ended before it listened"
        raise AssertionError("socat did not listen within 10 s")

    yield start
    for proc in procs:
        proc.terminate()
        proc.communicate(timeout=10)


def test_drip_feed_over_a_socket_url_with_back_pressure(
    bench_factory: Callable[..., Bench],
    device_server: Callable[[str], int],
    tmp_path: Path,
) -> None:
    # socket buffers between the PC and the server hold hundreds of kilobytes, so what the PC
    # wrote before the control's XOFF came back is bounded by them, not by a UART: overrun
    # detection is tested on paced lines
    limits = DncLimits(buffer_blocks=16, resume_blocks=4, overrun_blocks=1_000_000)
    options = SerialOptions(baud=115200, mode=parse_mode("dnc"), limits=limits)
    bench = bench_factory(options, baud=2_000_000, block_rate=2000)
    port = device_server(bench.pc_path)
    program = tmp_path / "p.nc"
    want = write_program(program, 3000, pad=100)
    report = stream_program(
        f"socket://127.0.0.1:{port}", program, safe_mode=False, config=DncConfig(chunk=256)
    )
    # the driver held the link until the control had taken the closing %
    bench.wait(lambda: bench.front.messages == ["RS232 DONE"], timeout=30)
    control = bench.sim.sim.control  # type: ignore[union-attr]
    assert bench.sim.call(lambda: control.machine.get(101)) == want
    assert bench.sim.call(lambda: control.runner.index) == 3002  # G21 + 3000 + M30
    assert report.bytes_sent == program.stat().st_size
    assert bench.front.xoffs > 0  # back-pressure did happen
    assert report.xoffs > 0  # and the PC saw it through the TCP stream
