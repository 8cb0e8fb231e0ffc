"""Concurrent readers and writers against ``opendnc serve`` (issue 20 item 1's figures).

Two rounds per database: a burst of 45 concurrent authenticated ``GET /api/programs`` (three
times), then 200 readers pacing like dashboards (one request every 2 s each) beside 4 uploaders
and 4 job makers for ``--seconds``. Prints answered requests, 5xx, hung requests and latency
percentiles; the machine's load average is printed too, as the figures depend on it.

    .venv/bin/python benchmarks/request_sessions.py
    .venv/bin/python benchmarks/request_sessions.py --db postgresql+psycopg://postgres@127.0.0.1/x
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import sys
import tempfile
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).parent))
from http_load import Connection, LoadResult, endpoint, readers_and_writers, timed
from served import start_serve, stop_serve


async def burst(url: str, key: str, size: int = 45, rounds: int = 3) -> LoadResult:
    """``size`` concurrent reads, ``rounds`` times."""
    result = LoadResult()
    host, port = endpoint(url)
    conns = [Connection(host, port, {"Authorization": f"Bearer {key}"}) for _ in range(size)]
    for _ in range(rounds):
        await asyncio.gather(
            *(timed(result, c, "GET", "/api/programs", hung_after=60) for c in conns)
        )
    for c in conns:
        c.close()
    return result


def measure(seconds: float, database: str | None) -> dict[str, Any]:
    """Both rounds against one fresh server."""
    with tempfile.TemporaryDirectory(prefix="opendnc-sessions-") as folder:
        proc, url, key = start_serve(Path(folder), database=database)
        try:
            mixed = asyncio.run(readers_and_writers(url, key, seconds=seconds, machine="m1"))
            bursts = asyncio.run(burst(url, key))
        finally:
            stop_serve(proc)
    return {
        "database": "postgresql" if database else "sqlite",
        "load_average": os.getloadavg()[0],
        "burst_45": bursts.as_json(),
        "readers_200_and_writers": mixed.as_json(),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=30.0)
    parser.add_argument("--db", default=None, help="database URL (default: a SQLite file)")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    result = measure(args.seconds, args.db)
    if args.json:
        print(json.dumps(result))
        return
    print(f"{result['database']}, load average {result['load_average']:.1f}")
    for name in ("burst_45", "readers_200_and_writers"):
        figures = result[name]
        print(
            f"  {name}: {figures['requests']} answered {figures['statuses']}, "
            f"hung {figures['hung']}, p50 {figures['p50_ms']} ms, p99 {figures['p99_ms']} ms, "
            f"max {figures['max_ms']} ms, p99 by method {figures['p99_ms_by_method']}"
        )


if __name__ == "__main__":
    main()
