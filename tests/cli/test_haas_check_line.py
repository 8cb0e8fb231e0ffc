"""`opendnc haas check-line`: add the program check line, then check files with it."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from opendnc.haas.verify import check_line

CLI = [sys.executable, "-m", "opendnc.cli.main"]
PROGRAM = b"%\nO01000 (FIRST)\nG00 G90 X0. Y0.\nG01 X-2.3600 F20.\nM30\n%\n"


def run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*CLI, *args], capture_output=True, text=True, timeout=60, check=False)


def test_add_then_check_then_a_damaged_copy_fails(tmp_path: Path) -> None:
    program = tmp_path / "O01000.nc"
    program.write_bytes(PROGRAM)
    missing = run("haas", "check-line", str(program))
    assert missing.returncode == 0
    assert missing.stdout.strip() == f"{program}: no check line (add one with --add)"

    added = run("haas", "check-line", str(program), "--add")
    assert added.returncode == 0, added.stderr
    result = check_line(program.read_bytes())
    assert result.ok
    assert added.stdout.strip() == f"{program}: ok ({result.actual})"
    assert program.read_bytes().split(b"\n")[2] == f"(ODNC CRC32 {result.actual})".encode()

    damaged = tmp_path / "O01000-punched.nc"
    damaged.write_bytes(program.read_bytes().replace(b"X-2.3600", b"X-2.2600"))
    both = run("haas", "check-line", str(program), str(damaged), "--json")
    assert both.returncode == 1
    rows = json.loads(both.stdout)
    assert [r["state"] for r in rows] == ["ok", "mismatch"]
    assert rows[1]["expected"] == result.actual != rows[1]["actual"]
