"""The command line end to end: `sim haas --serial`, `xmodem send`, `haas dnc`, `haas q`."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from opendnc.sim.cable import VirtualCable

from .conftest import PROGRAM
from .test_dnc_serial import write_program

CLI = [sys.executable, "-m", "opendnc.cli.main"]


def run(*args: str, timeout: float = 60) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*CLI, *args], capture_output=True, text=True, timeout=timeout)


@pytest.fixture
def serial_sim(tmp_path: Path) -> Iterator[tuple[str, int, Path]]:
    """A `sim haas` process in auto mode on side A of a cable: (PC port, MDC port, memory)."""
    root = tmp_path / "mem"
    with VirtualCable(baud=115200) as cable:
        proc = subprocess.Popen(
            [
                *CLI,
                "sim",
                "haas",
                "--serial",
                cable.path_a,
                "--baud",
                "115200",
                "--serial-mode",
                "auto",
                "--root",
                str(root),
                "--mdc-port",
                "0",
            ],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        try:
            assert proc.stdout is not None
            mdc_port = 0
            for line in proc.stdout:
                if line.startswith("MDC "):
                    mdc_port = int(line.rsplit(":", 1)[1])
                    break
            assert mdc_port, proc.stderr.read() if proc.stderr else "no MDC line"
            yield cable.path_b, mdc_port, root
        finally:
            proc.terminate()
            proc.communicate(timeout=10)  # also closes the pipes


def test_xmodem_send_then_drip_feed(serial_sim: tuple[str, int, Path], tmp_path: Path) -> None:
    port, mdc_port, root = serial_sim
    program = tmp_path / "O01000.nc"
    program.write_text(PROGRAM)
    sent = run(
        "xmodem",
        "send",
        str(program),
        "--port",
        port,
        "--baud",
        "115200",
        "--mode",
        "checksum",
        "--json",
    )
    assert sent.returncode == 0, sent.stderr
    assert (root / "O01000.nc").read_text() == PROGRAM

    refused = run("haas", "dnc", str(program), "--port", port)
    assert refused.returncode == 1
    assert len(refused.stderr.strip().splitlines()) == 1

    big = tmp_path / "dnc.nc"
    want = write_program(big, 500)
    fed = run(
        "haas", "dnc", str(big), "--port", port, "--baud", "115200", "--unsafe", "--chunk", "64"
    )
    assert fed.returncode == 0, fed.stderr
    assert "XOFF" in fed.stdout
    deadline = time.monotonic() + 20
    status = run("haas", "q", "Q500", "--port", str(mdc_port))
    while "BUSY" in status.stdout and time.monotonic() < deadline:  # the buffer still drains
        time.sleep(0.2)
        status = run("haas", "q", "Q500", "--port", str(mdc_port))
    assert "PROGRAM, O02000, IDLE, PARTS, 1" in status.stdout
    value = run("haas", "q", "Q600", "101", "--port", str(mdc_port), "--json")
    assert value.returncode == 0, value.stderr
    assert json.loads(value.stdout)["fields"]["value"] == want
