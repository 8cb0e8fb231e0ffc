"""Helpers for the serial-MDC, net share and DPRNT server tests: child processes, a fleet on its
own loop, a server started against it (kept apart from the other server tests' helpers)."""

from __future__ import annotations

import asyncio
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from concurrent.futures import Future
from pathlib import Path
from typing import Any, TypeVar

import pytest

from opendnc.sim.fleet import Fleet, server_config, start_fleet
from tests.peers import require_module

httpx = require_module("httpx")

T = TypeVar("T")
DEADLINE = 60.0


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


def wait_for(
    what: str,
    check: Callable[[], Any],
    timeout: float = DEADLINE,
    describe: Callable[[], Any] | None = None,
) -> Any:
    """Poll ``check`` until it returns something true; fail after ``timeout`` seconds."""
    end = time.monotonic() + timeout
    while True:
        value = check()
        if value:
            return value
        if time.monotonic() > end:
            detail = f": {describe()}" if describe is not None else ""
            raise AssertionError(f"{what} did not happen within {timeout:g} s{detail}")
        time.sleep(0.1)


def listening(port: int) -> Callable[[], bool]:
    def check() -> bool:
        try:
            socket.create_connection(("127.0.0.1", port), 0.2).close()
            return True
        except OSError:
            return False

    return check


def auth(key: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {key}"}


class Procs:
    """Child processes (``opendnc ...``), stopped at the end of the test."""

    def __init__(self, log_dir: Path) -> None:
        self.log_dir = log_dir
        self.procs: dict[str, subprocess.Popen[bytes]] = {}

    def start(self, name: str, *args: str) -> subprocess.Popen[bytes]:
        with (self.log_dir / f"{name}.log").open("ab") as log:
            proc = subprocess.Popen(
                [sys.executable, "-m", "opendnc.cli.main", *args],
                stdout=log,
                stderr=subprocess.STDOUT,
                start_new_session=True,
            )
        self.procs[name] = proc
        return proc

    def log(self, name: str) -> str:
        return (self.log_dir / f"{name}.log").read_text(errors="replace")

    def stop_all(self) -> None:
        for name, proc in list(self.procs.items()):
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGTERM)
                try:
                    proc.wait(10)
                except subprocess.TimeoutExpired:
                    os.killpg(proc.pid, signal.SIGKILL)
                    proc.wait(10)
            del self.procs[name]


@pytest.fixture
def procs(tmp_path: Path) -> Iterator[Procs]:
    logs = tmp_path / "logs"
    logs.mkdir()
    p = Procs(logs)
    try:
        yield p
    finally:
        p.stop_all()


class FleetThread:
    """A fleet of virtual controls on its own event loop thread."""

    def __init__(self, root: Path, **counts: int) -> None:
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()
        self.fleet: Fleet = self.run(lambda: start_fleet(root, **counts))

    def run(self, make: Callable[[], Any]) -> Any:
        return asyncio.run_coroutine_threadsafe(make(), self.loop).result(30)

    def call(self, fn: Callable[[], T]) -> T:
        future: Future[T] = Future()

        def go() -> None:
            try:
                future.set_result(fn())
            except BaseException as exc:
                future.set_exception(exc)

        self.loop.call_soon_threadsafe(go)
        return future.result(10)

    def stop(self) -> None:
        self.run(self.fleet.close)
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(10)
        self.loop.close()


def create_key(config: Path, db_url: str, role: str = "admin") -> str:
    return subprocess.run(
        [
            *(sys.executable, "-m", "opendnc.cli.main", "keys", "create", "--role", role),
            *("--config", str(config), "--db", db_url),
        ],
        capture_output=True,
        text=True,
        check=True,
        timeout=60,
    ).stdout.strip()


def serve_fleet(
    tmp_path: Path,
    fleet: FleetThread,
    procs: Procs,
    db_url: str,
    *,
    machine_keys: str = "",
    extra: str = "",
) -> tuple[Any, str]:
    """Start ``opendnc serve`` for the fleet's machines (serial Haas with ``mdc = true`` and
    ``machine_keys``; ``extra`` TOML appended); return an HTTP client and an admin key."""
    port = free_port()
    config = tmp_path / "shop.toml"
    text = server_config(
        fleet.fleet, bind=f"127.0.0.1:{port}", poll_interval=0.5, library=tmp_path / "lib", mdc=True
    )
    text = text.replace("mdc = true\n", "mdc = true\n" + machine_keys)
    config.write_text(text + "\n[requests]\ndelay = 0.5\n" + extra)
    key = create_key(config, db_url)
    procs.start("server", "serve", "--config", str(config), "--db", db_url)
    wait_for("the server", listening(port))
    return httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=30), key
