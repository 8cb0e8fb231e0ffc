"""`opendnc sim cable` end to end, as a separate process."""

from __future__ import annotations

import json
import os
import selectors
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
import serial

from opendnc.sim.cable import CableProcess

COMMAND = [sys.executable, "-m", "opendnc.cli.main", "sim", "cable"]


@contextmanager
def running_cable(*args: str) -> Iterator[tuple[subprocess.Popen[str], list[str]]]:
    proc = subprocess.Popen(
        [*COMMAND, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        assert proc.stdout is not None
        with selectors.DefaultSelector() as sel:
            sel.register(proc.stdout, selectors.EVENT_READ)
            assert sel.select(timeout=15), "no first line from the cable"
        first = proc.stdout.readline().split()
        yield proc, first
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait(5)


def read_exactly(port: serial.Serial, size: int) -> bytes:
    got = bytearray()
    deadline = time.monotonic() + 5
    while len(got) < size and time.monotonic() < deadline:
        got += port.read(size - len(got))
    return bytes(got)


def stop(proc: subprocess.Popen[str], sig: int) -> tuple[str, str]:
    proc.send_signal(sig)
    out, err = proc.communicate(timeout=10)
    assert proc.returncode == 0, err
    return out, err


def test_first_line_symlinks_traffic_and_stats_on_sigterm(tmp_path: Path) -> None:
    link_a, link_b = tmp_path / "cnc", tmp_path / "pc"
    with running_cable("--baud", "115200", "--link-a", str(link_a), "--link-b", str(link_b)) as (
        proc,
        paths,
    ):
        assert len(paths) == 2
        assert all(p.startswith("/dev/") for p in paths)
        assert os.readlink(link_a) == paths[0]
        assert os.readlink(link_b) == paths[1]
        a = serial.Serial(str(link_a), 115200, timeout=0.2)
        b = serial.Serial(str(link_b), 115200, timeout=0.2)
        data = os.urandom(3000)
        start = time.monotonic()
        a.write(data)
        assert read_exactly(b, 3000) == data
        assert time.monotonic() - start >= 3000 * 10 / 115200 * 0.99
        b.write(b"\x06" * 7)
        assert read_exactly(a, 7) == b"\x06" * 7
        a.close()
        b.close()
        out, _ = stop(proc, signal.SIGTERM)
    assert "a->b: carried 3000, delivered 3000, corrupted 0" in out
    assert "b->a: carried 7, delivered 7" in out
    assert "total: carried 3007, corrupted 0, dropped 0" in out
    assert not link_a.is_symlink()
    assert not link_b.is_symlink()


def test_noise_json_stats_on_sigint() -> None:
    args = ["--baud", "1000000", "--noise", "1e-3", "--drop", "1e-3", "--seed", "5", "--json"]
    with running_cable(*args) as (proc, paths):
        a = serial.Serial(paths[0], timeout=0.2)
        b = serial.Serial(paths[1], timeout=0.2)
        a.write(bytes(20_000))
        got = bytearray()
        on_line_until = time.monotonic() + 20_000 * 10 / 1_000_000
        while (chunk := b.read(4096)) or time.monotonic() < on_line_until:
            got += chunk
        a.close()
        b.close()
        out, _ = stop(proc, signal.SIGINT)
    stats = json.loads(out)
    ab = stats["a_to_b"]
    assert ab["carried"] == 20_000
    assert ab["delivered"] == len(got) == 20_000 - ab["dropped"]
    assert ab["corrupted"] == sum(1 for byte in got if byte) > 0
    assert ab["dropped"] > 0
    assert stats["b_to_a"]["carried"] == 0


@pytest.mark.parametrize(
    ("args", "message"),
    [(["--baud", "0"], "baud"), (["--noise", "3"], "bit-error rate")],
)
def test_bad_options_one_line_error(args: list[str], message: str) -> None:
    proc = subprocess.run([*COMMAND, *args], capture_output=True, text=True, timeout=30)
    assert proc.returncode == 1
    assert message in proc.stderr
    assert proc.stdout == ""


def test_cable_process_helper() -> None:
    with CableProcess(baud=230400, noise=0.0, seed=1) as cable:
        a = serial.Serial(cable.path_a, timeout=0.2)
        b = serial.Serial(cable.path_b, timeout=0.2)
        data = os.urandom(4000)
        start = time.monotonic()
        a.write(data)
        assert read_exactly(b, 4000) == data
        assert time.monotonic() - start >= 4000 * 10 / 230400 * 0.99
        a.close()
        b.close()
    assert cable.stats is not None
    assert cable.stats.a_to_b.delivered == 4000
    assert cable.stats.b_to_a.carried == 0
