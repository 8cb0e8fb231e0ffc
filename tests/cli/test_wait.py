"""`opendnc wait`: returns once a server listens (not before), fails in one line after the
deadline, and `opendnc --version` prints the version."""

from __future__ import annotations

import http.server
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from opendnc import __version__

CLI = [sys.executable, "-m", "opendnc.cli.main"]


def run(*args: str, timeout: float = 30) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*CLI, *args], capture_output=True, text=True, timeout=timeout)


def _later(seconds: float, action: object) -> threading.Timer:
    timer = threading.Timer(seconds, action)  # type: ignore[arg-type]
    timer.start()
    return timer


def test_tcp_waits_until_the_port_listens() -> None:
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))  # bound, not listening: connections are refused
    port = sock.getsockname()[1]
    listened: list[float] = []

    def listen() -> None:
        sock.listen()
        listened.append(time.monotonic())

    timer = _later(0.8, listen)
    try:
        done = run("wait", f"tcp://127.0.0.1:{port}", "--timeout", "10")
        finished = time.monotonic()
    finally:
        timer.cancel()
        sock.close()
    assert done.returncode == 0, done.stderr
    assert (done.stdout, done.stderr) == ("", "")
    assert listened, "wait returned before the port listened"
    assert finished >= listened[0]


class _Health(http.server.BaseHTTPRequestHandler):
    ready_at = 0.0

    def do_GET(self) -> None:
        code = 200 if time.monotonic() >= self.ready_at else 503
        self.send_response(code)
        self.send_header("Content-Length", "0")
        self.end_headers()

    def log_message(self, *args: object) -> None:
        pass


@pytest.fixture
def health() -> Iterator[tuple[str, type[_Health]]]:
    handler = type("Health", (_Health,), {"ready_at": time.monotonic() + 0.8})
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{server.server_address[1]}/api/health", handler
    server.shutdown()
    server.server_close()


def test_http_waits_for_a_2xx_answer(health: tuple[str, type[_Health]]) -> None:
    url, handler = health
    done = run("wait", url, "--timeout", "10")
    assert done.returncode == 0, done.stderr
    assert time.monotonic() >= handler.ready_at
    # a server that never gets ready: the last answer is named
    handler.ready_at = float("inf")
    late = run("wait", url, "--timeout", "0.6")
    assert late.returncode == 1
    assert late.stderr == f"error: {url} not ready after 0.6 s (answered 503)\n"


def test_a_path_and_a_refused_port_in_one_call(tmp_path: Path) -> None:
    flag = tmp_path / "ready"
    timer = _later(0.5, flag.touch)
    try:
        done = run("wait", str(flag), "--timeout", "10")
    finally:
        timer.cancel()
    assert done.returncode == 0, done.stderr
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
        refused = run("wait", str(flag), f"tcp://127.0.0.1:{port}", "--timeout", "0.5")
    assert refused.returncode == 1
    assert refused.stderr == (
        f"error: tcp://127.0.0.1:{port} not ready after 0.5 s (connection refused)\n"
    )


@pytest.mark.parametrize("target", ["tcp://127.0.0.1", "ftp://host/x", "tcp://:80", ""])
def test_a_bad_target_is_one_line(target: str) -> None:
    done = run("wait", target, "--timeout", "1")
    assert done.returncode == 1
    assert len(done.stderr.splitlines()) == 1, done.stderr
    assert done.stderr.startswith("error: ")


def test_version() -> None:
    done = run("--version")
    assert done.returncode == 0
    assert done.stdout == f"opendnc {__version__}\n"
