"""``opendnc serve`` in a child process for the benchmarks, and the figures read of it.

A separate process keeps the server's CPU time and memory apart from the measuring clients'.
The server has one machine that is switched off (an LSV2 control on a closed port): enough
for every API the benchmarks load.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
from pathlib import Path

SERVER_LINE = re.compile(rb"opendnc server on (http://\S+?)/ ")
START_LIMIT = 60.0
"""Seconds the server may take to print its address."""


def rss_mib(pid: int, field: str = "VmRSS") -> float:
    """A memory figure of process ``pid`` in MiB (``VmHWM``: its peak so far)."""
    text = Path(f"/proc/{pid}/status").read_text()
    found = re.search(rf"{field}:\s+(\d+) kB", text)
    return int(found.group(1)) / 1024 if found else 0.0


def cpu_seconds(pid: int) -> float:
    """User and system CPU seconds of process ``pid`` so far."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def start_serve(
    work: Path, *, clients: str = "", database: str | None = None
) -> tuple[subprocess.Popen[bytes], str, str]:
    """``opendnc serve`` on loopback with its files in ``work``, ``clients`` as its
    ``[clients]`` table (none when empty) and ``database`` (default: a SQLite file in
    ``work``); (process, URL, admin key). Its output goes to ``work/server.log``."""
    config = work / "shop.toml"
    config.write_text(
        f'[server]\nbind = "127.0.0.1:0"\n[library]\npath = "{work / "lib"}"\n\n'
        + (f"[clients]\n{clients}\n\n" if clients else "")
        + '[[machines]]\nname = "m1"\nkind = "lsv2"\nhost = "127.0.0.1"\nport = 9\n'
    )
    url = database or f"sqlite:///{work / 'opendnc.db'}"
    cli = [sys.executable, "-m", "opendnc.cli.main"]
    made = subprocess.run(
        [*cli, "keys", "create", "--role", "admin", "--config", str(config), "--db", url],
        capture_output=True,
        text=True,
        check=True,
        timeout=60,
    )
    log = work / "server.log"
    with log.open("wb") as out:
        proc = subprocess.Popen(
            [*cli, "serve", "--config", str(config), "--db", url, "--bind", "127.0.0.1:0"],
            stdout=out,
            stderr=subprocess.STDOUT,
        )
    deadline = time.monotonic() + START_LIMIT
    while time.monotonic() < deadline:
        found = SERVER_LINE.search(log.read_bytes())
        if found:
            return proc, found.group(1).decode(), made.stdout.strip()
        if proc.poll() is not None:
            break
        time.sleep(0.05)
    proc.kill()
    raise SystemExit(f"the server did not start: {log.read_text()[-2000:]}")


def stop_serve(proc: subprocess.Popen[bytes]) -> None:
    """Stop the server as an operator would (SIGTERM), killing it after 15 s."""
    proc.terminate()
    try:
        proc.wait(15)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
