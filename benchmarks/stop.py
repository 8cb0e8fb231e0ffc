"""How long SIGTERM and SIGINT take to stop ``opendnc serve`` under load, round after round.

Runs ``tests/server/test_stop.py`` (the server polling N virtual machines with an event stream
open, signalled alternately with SIGTERM and SIGINT) with many rounds on SQLite and PostgreSQL
and prints each backend's line: rounds, median and longest stop, every round's seconds. A round
that misses the deadline (10 s) fails the run.

    .venv/bin/python benchmarks/stop.py                      # 50 rounds, 200 machines
    .venv/bin/python benchmarks/stop.py --rounds 5 --machines 50 --backend sqlite
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=50)
    parser.add_argument("--machines", type=int, default=200)
    parser.add_argument("--backend", choices=("sqlite", "postgresql", "both"), default="both")
    args = parser.parse_args()
    env = dict(os.environ)
    env["OPENDNC_STOP_ROUNDS"] = str(args.rounds)
    env["OPENDNC_STOP_MACHINES"] = str(args.machines)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT / "src"), env.get("PYTHONPATH")]))
    selected = "tests/server/test_stop.py"
    if args.backend != "both":
        selected += f"::test_signals_stop_a_busy_server_within_the_deadline[{args.backend}]"
    command = [sys.executable, "-m", "pytest", "-q", "-s", "-p", "no:cacheprovider", "--timeout=0"]
    command.append(selected)
    wanted = ("stop rounds", "round ")
    tail: list[str] = []
    with subprocess.Popen(
        command, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    ) as run:
        assert run.stdout is not None
        for line in run.stdout:  # each round as it ends
            tail = [*tail[-80:], line]
            if line.startswith(wanted):
                print(line, end="", flush=True)
    if run.returncode != 0:
        print("".join(tail), file=sys.stderr)
    return run.returncode


if __name__ == "__main__":
    raise SystemExit(main())
