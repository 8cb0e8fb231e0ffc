"""`opendnc sim tnc` / `opendnc sim haas` on a port already taken: one line, exit 1."""

from __future__ import annotations

import socket
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest


@pytest.fixture
def taken_port() -> Iterator[int]:
    srv = socket.create_server(("127.0.0.1", 0))
    yield srv.getsockname()[1]
    srv.close()


def _run(args: list[str]) -> subprocess.CompletedProcess[str]:
    # a real process with a wide terminal so line-wrapping is the error's own doing
    env = {"COLUMNS": "80", "PATH": "/usr/bin:/bin"}
    return subprocess.run(
        [sys.executable, "-m", "opendnc.cli.main", *args],
        capture_output=True,
        text=True,
        timeout=30,
        env=env,
    )


def test_sim_tnc_port_in_use_is_one_line(taken_port: int, tmp_path: Path) -> None:
    done = _run(["sim", "tnc", "--port", str(taken_port), "--root", str(tmp_path)])
    assert done.returncode == 1
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, done.stderr
    assert lines[0].startswith("error: cannot listen on 127.0.0.1:")
    assert "address already in use" in lines[0]


def test_sim_haas_port_in_use_is_one_line(taken_port: int, tmp_path: Path) -> None:
    done = _run(["sim", "haas", "--mdc-port", str(taken_port), "--root", str(tmp_path)])
    assert done.returncode == 1
    assert "Traceback" not in done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, done.stderr
    assert lines[0].startswith("error: ")
    assert "address already in use" in lines[0]
