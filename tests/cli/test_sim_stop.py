"""Every simulator stops on Ctrl-C (SIGINT) and on SIGTERM with "stopped", status 0 and no
traceback, also while clients are connected (issue 23: `sim fleet` printed a CancelledError
from the virtual Haas's MDC server)."""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest

CLI = [sys.executable, "-m", "opendnc.cli.main"]
STOP_DEADLINE = 15.0


def _start(args: list[str], tmp_path: Path) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [*CLI, *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=tmp_path,
        env={**os.environ, "COLUMNS": "200"},
    )


def _read_until(proc: subprocess.Popen[str], pattern: str, deadline: float = 20.0) -> str:
    """Lines of stdout until one matches ``pattern``; returns everything read."""
    assert proc.stdout is not None
    seen = ""
    end = time.monotonic() + deadline
    while time.monotonic() < end:
        line = proc.stdout.readline()
        if not line:
            break
        seen += line
        if re.search(pattern, line):
            return seen
    proc.kill()
    raise AssertionError(f"no {pattern!r} in time: {seen!r} {proc.communicate()[1]!r}")


def _ports(text: str) -> list[int]:
    return [int(p) for p in re.findall(r"127\.0\.0\.1:(\d+)", text)]


def _stop(proc: subprocess.Popen[str], sig: int) -> tuple[int, str, str]:
    proc.send_signal(sig)
    try:
        out, err = proc.communicate(timeout=STOP_DEADLINE)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
        raise AssertionError(f"not stopped within {STOP_DEADLINE} s: {err}") from None
    return proc.returncode, out, err


def _connect(port: int, hello: bytes = b"") -> socket.socket:
    sock = socket.create_connection(("127.0.0.1", port), timeout=5)
    if hello:
        sock.sendall(hello)
        sock.recv(256)  # the reply: the session is running
    return sock


Setup = Callable[[Path], tuple[list[str], str, Callable[[str], list[socket.socket]]]]


def _tnc(tmp: Path) -> tuple[list[str], str, Callable[[str], list[socket.socket]]]:
    args = ["sim", "tnc", "--port", "0", "--root", str(tmp / "tnc")]
    return args, r"listening on", lambda out: [_connect(_ports(out)[0])]


def _haas(tmp: Path) -> tuple[list[str], str, Callable[[str], list[socket.socket]]]:
    args = ["sim", "haas", "--root", str(tmp / "mem"), "--mdc-port", "0", "--dprnt", "tcp:0"]

    def clients(out: str) -> list[socket.socket]:
        mdc, dprnt = _ports(out)[:2]
        return [_connect(mdc, b"?Q100\r\n"), _connect(dprnt)]

    return args, r"^DPRNT tcp", clients


def _fleet(tmp: Path) -> tuple[list[str], str, Callable[[str], list[socket.socket]]]:
    config = tmp / "shop.toml"
    args = ["sim", "fleet", "--tnc", "1", "--haas", "1", "--serial-haas", "1"]
    args += ["--root", str(tmp / "fleet"), "--config-out", str(config)]

    def clients(_out: str) -> list[socket.socket]:
        text = config.read_text()
        mdc = int(re.search(r"mdc_port = (\d+)", text).group(1))  # type: ignore[union-attr]
        tnc = int(re.search(r"\nport = (\d+)", text).group(1))  # type: ignore[union-attr]
        return [_connect(mdc, b"?Q100\r\n"), _connect(tnc)]

    return args, r"^fleet of", clients


def _cable(tmp: Path) -> tuple[list[str], str, Callable[[str], list[socket.socket]]]:
    return ["sim", "cable"], r"^/dev/", lambda _out: []


def _haas_waiting(tmp: Path) -> tuple[list[str], str, Callable[[str], list[socket.socket]]]:
    """`--run` waits for a DPRNT reader that never comes: a stop must not wait for it."""
    memory = tmp / "mem"
    memory.mkdir()
    (memory / "O00100.nc").write_text("%\nO00100\nDPRNT[HELLO]\nM30\n%\n")
    args = ["sim", "haas", "--root", str(memory), "--mdc-port", "0", "--dprnt", "tcp:0"]
    return [*args, "--run", "100"], r"^MEMORY", lambda _out: []


def _fanuc(tmp: Path) -> tuple[list[str], str, Callable[[str], list[socket.socket]]]:
    # its serial line: a TCP port on loopback (a serial device server), closed by the test
    line = socket.create_server(("127.0.0.1", 0))
    port = line.getsockname()[1]
    args = ["sim", "fanuc", "--serial", f"tcp://127.0.0.1:{port}", "--root", str(tmp / "fanuc")]
    return args, r"^MODE ", lambda _out: [line]


SIMULATORS = {
    "tnc": _tnc,
    "haas": _haas,
    "haas-run": _haas_waiting,
    "fleet": _fleet,
    "cable": _cable,
    "fanuc": _fanuc,
}


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
@pytest.mark.parametrize("name", list(SIMULATORS))
def test_simulator_stops_cleanly(name: str, sig: int, tmp_path: Path) -> None:
    args, ready, clients = SIMULATORS[name](tmp_path)
    flag = tmp_path / "sim.ready"
    if name != "cable":  # the cable's device links are its readiness
        args = [*args, "--ready-file", str(flag)]
    proc = _start(args, tmp_path)
    try:
        out = _read_until(proc, ready)
        sockets = clients(out)
        deadline = time.monotonic() + 10
        while name != "cable" and not flag.exists() and time.monotonic() < deadline:
            time.sleep(0.01)
        assert name == "cable" or flag.exists(), "--ready-file never appeared"
    except BaseException:
        proc.kill()
        proc.communicate()
        raise
    started = time.monotonic()
    try:
        code, rest, err = _stop(proc, sig)
    finally:
        for sock in sockets:
            sock.close()
    assert time.monotonic() - started < 10  # not held by a wait for a reader (30 s)
    assert not flag.exists()  # a stopped simulator is not ready
    assert "Traceback" not in err, err
    assert "Error" not in err, err
    assert code == 0, err
    if name == "cable":
        assert rest.startswith("a->b: carried"), rest  # its counters, then nothing else
    else:
        assert rest.strip().endswith("stopped"), rest
