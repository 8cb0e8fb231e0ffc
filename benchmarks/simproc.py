"""The virtual TNC in a child process for the benchmarks (``opendnc sim tnc --port 0``).

A separate process keeps the simulator's CPU time and GIL apart from the measured clients.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
from pathlib import Path

START_LIMIT = 20.0
"""Seconds the simulator may take to print its listening address."""


def start_server(
    root: Path, *, profile: str = "tnc320", loop: str | None = None
) -> tuple[subprocess.Popen[str], int]:
    """Run the simulator CLI in a child process and read back its port.

    ``loop="asyncio"`` makes the simulator use the standard event loop, any other string its
    default loop; ``None`` leaves the choice to the inherited ``OPENDNC_SIM_LOOP``.
    """
    env = dict(os.environ)
    if loop == "asyncio":
        env["OPENDNC_SIM_LOOP"] = "asyncio"
    elif loop is not None:
        env.pop("OPENDNC_SIM_LOOP", None)
    command = [sys.executable, "-m", "opendnc.cli.main", "sim", "tnc", "--port", "0"]
    command += ["--root", str(root), "--profile", profile]
    proc = subprocess.Popen(
        command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env
    )
    assert proc.stdout is not None
    deadline = time.monotonic() + START_LIMIT
    while time.monotonic() < deadline:
        found = re.search(r"listening on [\d.]+:(\d+)", proc.stdout.readline())
        if found:
            return proc, int(found.group(1))
    proc.kill()
    raise SystemExit("simulator did not start")
