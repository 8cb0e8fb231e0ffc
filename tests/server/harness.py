"""What the server tests share: child processes, ports, keys, polling with deadlines."""

from __future__ import annotations

import contextlib
import os
import re
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from tests.peers import require_module

httpx = require_module("httpx")

DEADLINE = 60.0


def free_port() -> int:
    """A TCP port nothing listens on right now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


# the longest pause between two polls of :func:`wait_for`
POLL_MAX_S = 0.25


def wait_for(
    what: str,
    check: Callable[[], Any],
    timeout: float = DEADLINE,
    describe: Callable[[], Any] | None = None,
) -> Any:
    """Poll ``check`` until it returns something true; fail naming ``what`` at the deadline.

    The pause grows from 20 ms to a quarter of a second: most waits end within a few polls,
    and a long one (a transfer, a failover) must not spend the test machine's CPU on asking a
    server forty times a second (a tenth of the end-to-end tests' CPU, measured)."""
    end = time.monotonic() + timeout
    pause = 0.02
    while True:
        value = check()
        if value:
            return value
        if time.monotonic() > end:
            detail = f": {describe()}" if describe is not None else ""
            raise AssertionError(f"timed out waiting for {what}{detail}")
        time.sleep(pause)
        pause = min(POLL_MAX_S, pause * 1.5)


def listening(port: int) -> Callable[[], bool]:
    """A check that ``port`` on loopback accepts connections."""

    def check() -> bool:
        try:
            socket.create_connection(("127.0.0.1", port), 0.2).close()
            return True
        except OSError:
            return False

    return check


class Procs:
    """Child processes, stopped at the end of the test."""

    def __init__(self, log_dir: Path) -> None:
        self.log_dir = log_dir
        self.procs: dict[str, subprocess.Popen[bytes]] = {}

    def start(self, name: str, *args: str) -> subprocess.Popen[bytes]:
        with (self.log_dir / f"{name}.log").open("ab") as log:  # the child keeps its own fd
            proc = subprocess.Popen(
                [sys.executable, "-m", "opendnc.cli.main", *args],
                stdout=log,
                stderr=subprocess.STDOUT,
                start_new_session=True,
            )
        self.procs[name] = proc
        return proc

    def stop(self, name: str, sig: int = signal.SIGTERM) -> None:
        proc = self.procs.pop(name)
        if proc.poll() is None:
            os.killpg(proc.pid, sig)
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(10)

    def log(self, name: str) -> str:
        return (self.log_dir / f"{name}.log").read_text(errors="replace")

    def stop_all(self) -> None:
        """Stop every child: all are signalled first, then waited for, so their shutdowns
        overlap (a server, its machines and their links each take up to a second)."""
        procs = list(self.procs.values())
        self.procs.clear()
        running = [p for p in procs if p.poll() is None]
        for proc in running:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGTERM)
        deadline = time.monotonic() + 10
        for proc in running:
            try:
                proc.wait(max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(10)


def create_key(
    config: Path, db_url: str, role: str = "admin", user: str | None = None, *, cli: bool = False
) -> str:
    """A new API key for ``user`` (made with the role if missing).

    ``cli``: made the way an admin makes one, ``opendnc keys create``, in a process of its own.
    Otherwise made here through the same calls (migrate, then :func:`auth.create_key`): the
    command's process costs nearly a CPU second each time, and a test makes several."""
    args = ["keys", "create", "--role", role, "--config", str(config), "--db", db_url]
    if user is not None:
        args += ["--user", user]
    if cli:
        done = subprocess.run(
            [sys.executable, "-m", "opendnc.cli.main", *args],
            capture_output=True,
            text=True,
            timeout=60,
            check=False,
        )
        assert done.returncode == 0, done.stderr
        return done.stdout.strip()
    from opendnc.server.access import auth
    from opendnc.server.store.db import make_engine, make_sessions, migrate
    from opendnc.server.store.models import Role

    parsed = Role.parse(role)
    engine = make_engine(db_url)
    try:
        migrate(engine)
        with make_sessions(engine).begin() as session:
            _row, key = auth.create_key(
                session,
                user or parsed.name.lower(),
                parsed,
                actor="cli",
                create_user_role=parsed,
            )
    finally:
        engine.dispose()
    return key


SERVER_LINE = re.compile(rb"opendnc server on (http://\S+?)/ ")


def serve(procs: Procs, config: Path, db_url: str, *args: str, name: str = "server") -> str:
    """``opendnc serve`` as a child process; its base URL once it says it listens.

    The server binds a port the system picks (``--bind 127.0.0.1:0``) and the URL is read from
    the line it prints once it listens. A port chosen beforehand can be taken meanwhile (by
    another test's process or an outgoing connection); the server then could not start, and a
    check that "something listens on the port" would hand the test to that stranger, whose
    silence looked like a server that never answers. A server that exits fails at once, with
    its log.
    """
    log = procs.log_dir / f"{name}.log"
    start = log.stat().st_size if log.exists() else 0  # a restart appends to the same log
    proc = procs.start(
        name, "serve", "--config", str(config), "--db", db_url, "--bind", "127.0.0.1:0", *args
    )

    def announced() -> str | None:
        with log.open("rb") as f:
            f.seek(start)
            text = f.read()
        found = SERVER_LINE.search(text)
        if found is not None:
            return found.group(1).decode()
        if proc.poll() is not None:
            raise AssertionError(
                f"the server exited with {proc.returncode}: {text.decode(errors='replace')}"
            )
        return None

    url: str = wait_for("the server", announced, describe=lambda: procs.log(name))
    return url


def start_server(procs: Procs, config: Path, db_url: str, *args: str) -> httpx.Client:
    """``opendnc serve`` as a child process (see :func:`serve`); a client once it listens."""
    return httpx.Client(base_url=serve(procs, config, db_url, *args), timeout=30)


def auth(key: str) -> dict[str, str]:
    """The header that carries an API key."""
    return {"Authorization": f"Bearer {key}"}


def wait_jobs(client: httpx.Client, key: str, ids: list[int]) -> list[dict[str, Any]]:
    """The jobs ``ids`` once none is queued or running any more."""

    def fetch() -> list[dict[str, Any]]:
        return [client.get(f"/api/jobs/{i}", headers=auth(key)).json() for i in ids]

    def describe() -> list[tuple[Any, ...]]:
        return [(j["id"], j["machine"], j["state"], j["attempts"], j["error"]) for j in fetch()]

    def done() -> list[dict[str, Any]] | None:
        jobs = fetch()
        return jobs if all(j["state"] not in ("queued", "running") for j in jobs) else None

    result: list[dict[str, Any]] = wait_for("the jobs", done, describe=describe)
    return result
