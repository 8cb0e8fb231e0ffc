"""End to end over RS-232: `opendnc sim cable` between the PC and the virtual Haas; the
program goes by XModem (or drip-feed with --unsafe), DPRNT comes back on the same port."""

from __future__ import annotations

import json
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest

from opendnc.sim.haas import DprntDestination, SimOptions
from opendnc.sim.haas.serial_front import SerialFrontEnd, SerialOptions, parse_mode, start_serial

from .conftest import CLI, GRID, GRID_ARGS, Haas, analytic, make_haas, probing_config, run_until
from .test_measure_tcp import check_points


@pytest.fixture
def cable() -> Iterator[tuple[str, str]]:
    """`opendnc sim cable` in its own process: (control side, PC side)."""
    proc = subprocess.Popen(
        [*CLI, "sim", "cable", "--baud", "115200"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        first = proc.stdout.readline().split()
        assert len(first) == 2, proc.stderr.read() if proc.stderr else "no paths"
        yield first[0], first[1]
    finally:
        proc.terminate()
        proc.communicate(timeout=10)


@pytest.fixture
def serial_haas(tmp_path: Path, cable: tuple[str, str]) -> Iterator[tuple[Haas, str]]:
    """A virtual Haas in serial auto mode (XModem receive, text runs as DNC, DPRNT out)."""
    config = probing_config(DprntDestination.SERIAL)
    haases = make_haas(tmp_path, config, SimOptions(mdc_port=0))
    haas = next(haases)
    sim = haas.thread.sim
    assert sim is not None
    options = SerialOptions(baud=115200, mode=parse_mode("auto"))

    async def attach() -> SerialFrontEnd:
        front = await start_serial(sim, cable[0], 115200, None, options)
        sim.add_front_end(front)
        return front

    haas.thread._submit(attach())
    yield haas, cable[1]
    haases.close()


def check_summary(stdout: str) -> None:
    summary = json.loads(stdout)
    want = analytic(GRID)
    assert abs(summary["tilt"]["x"]["slope"] - want["a"]) < 2e-4
    assert abs(summary["tilt"]["y"]["slope"] - want["b"]) < 2e-4
    assert abs(summary["flatness"] - want["flatness"]) < 2e-4
    assert summary["missing"] == []


def test_measure_by_xmodem_then_cycle_start(serial_haas: tuple[Haas, str], tmp_path: Path) -> None:
    haas, port = serial_haas
    report = tmp_path / "report.html"
    result = run_until(
        [
            "surface",
            "measure",
            "--haas",
            port,
            "--baud",
            "115200",
            *GRID_ARGS,
            "-o",
            str(report),
            "--stl",
            str(tmp_path / "s.stl"),
            "--timeout",
            "30",
            "--json",
        ],
        "waiting for cycle start",
        lambda: haas.start(1234),
    )
    assert result.returncode == 0, result.stderr
    assert "O01234 loaded" in result.stderr
    assert (haas.root / "O01234.nc").exists()  # stored by the control's XModem receiver
    check_points(report.with_suffix(".csv"), haas.printed)
    check_summary(result.stdout)
    stl = (tmp_path / "s.stl").read_bytes()
    assert int.from_bytes(stl[80:84], "little") == 2 * 7 * 5  # two triangles per grid cell


def test_measure_unsafe_drip_feeds_and_captures(
    serial_haas: tuple[Haas, str], tmp_path: Path
) -> None:
    haas, port = serial_haas
    report = tmp_path / "report.html"
    args = ["surface", "measure", "--haas", port, "--baud", "115200", *GRID_ARGS]
    result = subprocess.run(
        [*CLI, *args, "-o", str(report), "--timeout", "30", "--unsafe", "--json"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 0, result.stderr
    assert "drip-feeding O01234" in result.stderr
    assert not (haas.root / "O01234.nc").exists()  # run from the stream, never stored
    check_points(report.with_suffix(".csv"), haas.printed)
    check_summary(result.stdout)
