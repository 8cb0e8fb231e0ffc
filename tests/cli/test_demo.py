"""`opendnc demo` as a subprocess: it must finish quickly and show real values."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
from pathlib import Path

from opendnc.sim.tnc import get_profile, start_tnc


def fresh_tnc640(root: Path) -> tuple[dict[str, int], dict[str, float]]:
    """Sizes of the programs in TNC:\\nc_prog and the axis positions of a fresh TNC 640."""
    with start_tnc("tnc640", root=root) as tnc:
        positions = tnc.call(lambda c: dict(c.machine.positions))
    folder = root / "TNC" / "nc_prog"
    return {p.name: p.stat().st_size for p in folder.iterdir() if p.is_file()}, positions


def test_demo_shows_live_values(tmp_path: Path) -> None:
    started = time.monotonic()
    proc = subprocess.run(
        [sys.executable, "-m", "opendnc.cli.main", "demo", "--tour"],
        capture_output=True,
        text=True,
        timeout=60,
        env={**os.environ, "COLUMNS": "200"},
    )
    elapsed = time.monotonic() - started
    assert proc.returncode == 0, proc.stderr
    assert elapsed < 20
    out = proc.stdout
    profile = get_profile("tnc640")
    assert profile.model in out
    assert profile.nc_software in out
    assert "TNC 128/320/620/640" in out
    # the listing shows the sizes a fresh root really has, for every program in it
    sizes, positions = fresh_tnc640(tmp_path)
    assert "POCKET.H" in sizes
    for name, size in sizes.items():
        assert re.search(rf"{re.escape(name)}\s*\S\s*{size}\b", out), (name, size)
    assert "bytes identical" in out
    assert "manual" in out
    assert "idle" in out
    for axis, value in positions.items():
        assert f"{axis}={value:.4f}" in out
    assert "10000" in out
    # overrides as `opendnc lsv2 status` shows them (issue 23: the tour printed None)
    assert "feed 100 %  spindle 100 %  rapid 100 %" in out
    assert "None" not in out
    assert "MILL_D10_ROUGH" in out  # tool table
    assert "Q500" in out
    assert "PROGRAM" in out
    assert "demo finished" in out


def test_demo_server_sends_a_program_to_every_virtual_machine() -> None:
    # `make demo` runs the server demo; --check does one round trip and exits. The computer's
    # zone (TZ here) is the shop's clock: the pages show the times of the people using them.
    proc = subprocess.run(
        [sys.executable, "-m", "opendnc.cli.main", "demo", "--check", "--bind", "127.0.0.1:0"],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "COLUMNS": "200", "TZ": "America/Chicago"},
    )
    assert proc.returncode == 0, proc.stderr
    out = proc.stdout
    assert "login: admin / " in out
    assert "API key: odk_" in out
    assert "all machines online" in out
    for machine in ("tnc-1", "tnc-2"):
        assert f"POCKET.H -> {machine}: sent" in out
    for machine in ("haas-1", "haas-serial-1"):
        assert f"O01000.nc -> {machine}: sent" in out
    # the virtual Fanuc, a tape-code control of the serial kind
    assert "O0100.nc -> fanuc-1: sent" in out
    assert "fanuc-1 (serial)" in out
    # the NGC has a DPRNT source and runs a program that prints (issue 23)
    assert "DPRNT haas-1: BORE  1 DIA  1.0002" in out
    assert "DPRNT haas-1: BORE  3 DIA  1.0000" in out
    assert "times in America/Chicago" in out
    # a machine behind the virtual MTConnect agent, and a control that takes its programs
    # through its FTP folder (status through the agent too): online, and the FTP one is sent to
    assert "mtc-1 (mtconnect)" in out
    assert "ftp-1 (mtconnect)" in out
    assert "O01000.nc -> ftp-1: sent" in out
    # the OPC UA machine's server takes seconds of CPU to build: --check leaves it out
    assert "opc-1" not in out
    assert "leaves out the OPC UA machine" in out
    # the demo has a net share: its NAS folder's programs reach the NGC's share
    assert "net share -> haas-1: O01000.nc, O02000.nc, O04000.nc, O05000.nc" in out
