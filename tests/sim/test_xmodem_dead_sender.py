"""Issue 15, item 5: a sender that dies mid-transfer must not keep ``xmodem recv`` waiting.

Where the port reports the other end gone (a pty whose other side closed, EOF on TCP) the
receive ends at once; where it cannot (the virtual cable, like a real cable without modem
lines), ``--timeout`` bounds the whole wait, retries included, instead of 10 x 10 s.
The sender is a separate process killed halfway; each wait is polled against a deadline.
"""

from __future__ import annotations

import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from opendnc.sim.cable import VirtualCable

OPENDNC = [sys.executable, "-m", "opendnc.cli.main"]
SENDER = [sys.executable, str(Path(__file__).with_name("xmodem_dying_sender.py"))]


@contextmanager
def dying_sender(*args: str) -> Iterator[tuple[subprocess.Popen[str], str]]:
    proc = subprocess.Popen([*SENDER, *args], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        yield proc, proc.stdout.readline().strip()
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.communicate(timeout=10)


def receive_until_killed(
    sender: subprocess.Popen[str], port: str, out: Path, timeout: float, limit: float
) -> tuple[float, int, str]:
    """Start ``xmodem recv``, kill the sender once it is midway; seconds until recv ended."""
    rx = subprocess.Popen(
        [*OPENDNC, "xmodem", "recv", str(out), "--port", port, "--timeout", str(timeout)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert sender.stdout is not None
        assert sender.stdout.readline().strip() == "midway"
        sender.kill()
        killed = time.monotonic()
        deadline = killed + limit
        while rx.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        waited = time.monotonic() - killed
        assert rx.poll() is not None, f"recv still waiting {limit:g} s after the sender died"
        _, err = rx.communicate(timeout=10)
        return waited, rx.returncode, " ".join(err.split())
    finally:
        if rx.poll() is None:
            rx.kill()
            rx.communicate()


def test_pty_hangup_ends_the_receive_at_once(tmp_path: Path) -> None:
    with dying_sender("pty") as (sender, path):
        waited, code, err = receive_until_killed(sender, path, tmp_path, 60, limit=5)
    assert code == 1
    assert "closed" in err, err
    assert list(tmp_path.iterdir()) == []
    assert waited < 5


def test_tcp_eof_ends_the_receive_at_once(tmp_path: Path) -> None:
    with dying_sender("tcp") as (sender, url):
        waited, code, err = receive_until_killed(sender, url, tmp_path, 60, limit=5)
    assert code == 1
    assert "closed" in err, err
    assert list(tmp_path.iterdir()) == []
    assert waited < 5


@pytest.mark.parametrize("timeout", [3.0])
def test_timeout_bounds_the_wait_on_a_cable(tmp_path: Path, timeout: float) -> None:
    """No hang-up crosses the cable: ``--timeout`` is the bound (today: 100-110 s)."""
    with VirtualCable(baud=115200) as cable, dying_sender("serial", cable.path_a) as (sender, _):
        waited, code, err = receive_until_killed(
            sender, cable.path_b, tmp_path, timeout, limit=timeout + 10
        )
    assert code == 1
    assert f"no good block from the sender for {timeout:g} s" in err, err
    assert list(tmp_path.iterdir()) == []
    assert waited < timeout + 3
