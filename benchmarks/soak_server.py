"""The server part of ``benchmarks/soak.py``: ``opendnc serve`` under readers, writers and abuse.

For the whole soak, at once: 200 readers pacing like dashboards and writers uploading versions
and queueing jobs (``http_load``); slowloris sockets sending a header byte every 2 s; slow
bodies trickling a byte every 2 s; server-sent-event streams opened, held a few seconds and
dropped; 20 clients sending bad input (huge ids, a 60,000-character search, non-UTF-8 and
non-finite bodies, oversized bodies). Reports every 5xx, hung requests (no answer within 30 s),
slow sockets held past their deadline, p99 latency and the server's memory (baseline, peak,
after).
"""

from __future__ import annotations

import asyncio
import random
import tempfile
import time
from collections import Counter
from pathlib import Path
from typing import Any

from http_load import Connection, LoadResult, endpoint, readers_and_writers, timed
from opendnc.server.http.limits import Limits
from served import rss_mib, start_serve, stop_serve

LIMITS = Limits()

BAD: list[tuple[str, str, bytes, str]] = [
    ("GET", "/api/jobs/99999999999999999999", b"", ""),
    ("GET", "/api/audit?before=9223372036854775808", b"", ""),
    ("GET", "/api/jobs/2147483648", b"", ""),
    ("GET", "/api/programs?q=" + "a" * 60000, b"", ""),
    ("GET", "/api/programs?q=%25_%25", b"", ""),
    ("POST", "/api/keys", b"\xff\xfe\x80\x81", "application/octet-stream"),
    ("POST", "/api/keys", b'{"user":"\xff","role":"viewer"}', "application/json"),
    (
        "POST",
        "/api/jobs",
        b'{"program":"LOAD0.nc","version":1e400,"machines":["m1"]}',
        "application/json",
    ),
    (
        "POST",
        "/api/jobs",
        b'{"program":"LOAD0.nc","version":NaN,"machines":["m1"]}',
        "application/json",
    ),
    ("POST", "/api/jobs", b'{"program":"LOAD0.nc","machines":[]}', "application/json"),
    ("POST", "/api/jobs", b"[" * 5000, "application/json"),
    ("PUT", "/api/programs/O1.nc.", b"G0\n", ""),
    ("PUT", "/api/programs/load0.NC", b"G0\n", ""),
    ("PUT", "/api/programs/%2e%2e", b"G0\n", ""),
    ("GET", "/api/programs/LOAD0.nc/diff?a=1&b=99999999999999999999", b"", ""),
    ("POST", "/api/jobs/1/move", b'{"index":1e400}', "application/json"),
    ("GET", "/api/inbox/-1", b"", ""),
]


class Slow:
    """Sockets that trickle a request, and how long the server let each live."""

    def __init__(self) -> None:
        self.held: list[float] = []
        self.answers: Counter[str] = Counter()


async def trickle(port: int, head: bytes, tail: bytes, slow: Slow, end: float) -> None:
    """Send ``head`` at once, then ``tail`` a byte every 2 s, until the server closes."""
    while time.monotonic() < end:
        begun = time.monotonic()
        try:
            reader, writer = await asyncio.open_connection("127.0.0.1", port)
        except OSError:
            slow.answers["connect refused"] += 1
            await asyncio.sleep(1)
            continue
        answer = b""
        try:
            writer.write(head)
            for byte in tail:
                writer.write(bytes([byte]))
                await writer.drain()
                try:
                    answer = await asyncio.wait_for(reader.read(200), 2)
                except TimeoutError:
                    continue
                break
        except ConnectionError:
            pass
        slow.held.append(time.monotonic() - begun)
        slow.answers[answer[:12].decode("latin-1") or "closed"] += 1
        writer.close()


async def streams(port: int, key: str, end: float, rng: random.Random, tally: Counter[str]) -> None:
    """Open an event stream, read it a few seconds, drop it; again until ``end``."""
    request = f"GET /api/events HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer {key}\r\n\r\n"
    while time.monotonic() < end:
        try:
            reader, writer = await asyncio.open_connection("127.0.0.1", port)
            writer.write(request.encode())
            status = await asyncio.wait_for(reader.readline(), 30)
            tally[status[9:12].decode("latin-1") or "closed"] += 1
            hold = time.monotonic() + rng.uniform(1, 5)
            while time.monotonic() < hold:
                await asyncio.wait_for(reader.read(4096), 30)
            writer.close()
        except (OSError, TimeoutError) as exc:
            tally[type(exc).__name__] += 1
            await asyncio.sleep(1)


async def abuse(url: str, key: str, end: float, rng: random.Random, result: LoadResult) -> None:
    """Bad input, over and over, on one connection."""
    host, port = endpoint(url)
    conn = Connection(host, port, {"Authorization": f"Bearer {key}"})
    while time.monotonic() < end:
        method, path, body, ctype = rng.choice(BAD)
        if rng.random() < 0.1:
            # An oversized JSON body, announced: the server answers 413 without reading it.
            big = Connection(
                host, port, {"Authorization": f"Bearer {key}", "Content-Length": "1200000"}
            )
            await timed(result, big, "GET", "/api/jobs", hung_after=30)
            big.close()
            continue
        await timed(result, conn, method, path, body=body, ctype=ctype, hung_after=30)
    conn.close()


def soak_server(
    seconds: float, smoke: bool, seed: int, database: str | None = None
) -> dict[str, Any]:
    """Run the server part for ``seconds`` (``smoke``: a few seconds, fewer clients)."""
    rng = random.Random(seed)
    readers, slowloris, slow_bodies, sse, abusers = (
        (40, 20, 5, 20, 4) if smoke else (200, 200, 50, 200, 20)
    )
    with tempfile.TemporaryDirectory(prefix="opendnc-soak-server-") as folder:
        work = Path(folder)
        # one key opens every event stream of the soak (docs/server.md#bounded-clients)
        proc, url, key = start_serve(work, clients="streams_per_user = 2000", database=database)
        _host, port = endpoint(url)
        try:
            time.sleep(1)
            baseline = rss_mib(proc.pid)
            headers, bodies = Slow(), Slow()
            stream_tally: Counter[str] = Counter()
            bad = LoadResult()

            async def everything() -> LoadResult:
                end = time.monotonic() + seconds
                head = b"PUT /api/programs/SLOW.nc HTTP/1.1\r\nHost: x\r\n"
                head += f"Authorization: Bearer {key}\r\nContent-Length: 100000\r\n\r\n".encode()
                tasks = [
                    *(
                        trickle(
                            port, b"", b"GET /api/health HTTP/1.1\r\nX: " + b"a" * 200, headers, end
                        )
                        for _ in range(slowloris)
                    ),
                    *(trickle(port, head, b"G" * 100000, bodies, end) for _ in range(slow_bodies)),
                    *(
                        streams(port, key, end, random.Random(rng.random()), stream_tally)
                        for _ in range(sse)
                    ),
                    *(
                        abuse(url, key, end, random.Random(rng.random()), bad)
                        for _ in range(abusers)
                    ),
                ]
                load, *_ = await asyncio.gather(
                    readers_and_writers(
                        url, key, seconds=seconds, readers=readers, machine="m1", seed=seed
                    ),
                    *tasks,
                )
                result: LoadResult = load
                return result

            load = asyncio.run(everything())
            peak = rss_mib(proc.pid, "VmHWM")
            time.sleep(5)
            after = rss_mib(proc.pid)
            alive = proc.poll() is None
        finally:
            stop_serve(proc)
        log = (work / "server.log").read_text(errors="replace")
    header_deadline = LIMITS.header_timeout + 3
    body_deadline = LIMITS.body_timeout + 3
    return {
        "database": "postgresql" if database else "sqlite",
        "seconds": seconds,
        "load": load.as_json(),
        "abuse": bad.as_json(),
        "five_xx": len(load.five_xx) + len(bad.five_xx),
        "five_xx_examples": (load.five_xx + bad.five_xx)[:10],
        "hung": load.hung + bad.hung,
        "slow_headers": {
            "sockets": len(headers.held),
            "held_past_deadline": sum(t > header_deadline for t in headers.held),
            "max_held_s": round(max(headers.held, default=0), 1),
            "answers": dict(headers.answers),
        },
        "slow_bodies": {
            "sockets": len(bodies.held),
            "held_past_deadline": sum(t > body_deadline for t in bodies.held),
            "max_held_s": round(max(bodies.held, default=0), 1),
            "answers": dict(bodies.answers),
        },
        "event_streams": dict(stream_tally),
        "memory_mib": {
            "baseline": round(baseline, 1),
            "peak": round(peak, 1),
            "after": round(after, 1),
        },
        "server_alive": alive,
        "server_tracebacks": log.count("Traceback"),
    }


def report(part: dict[str, Any]) -> None:
    """Print the server part's figures."""
    load, slow_h, slow_b = part["load"], part["slow_headers"], part["slow_bodies"]
    print(
        f"server ({part['database']}): {load['requests']} requests, p50 {load['p50_ms']} ms, "
        f"p99 {load['p99_ms']} ms (by method {load['p99_ms_by_method']}), "
        f"5xx {part['five_xx']}, hung {part['hung']}"
    )
    print(f"  abuse: {part['abuse']['requests']} requests, statuses {part['abuse']['statuses']}")
    print(
        f"  slow headers: {slow_h['sockets']} sockets, {slow_h['held_past_deadline']} held past "
        f"the deadline (max {slow_h['max_held_s']} s); slow bodies: {slow_b['sockets']}, "
        f"{slow_b['held_past_deadline']} past (max {slow_b['max_held_s']} s)"
    )
    memory = part["memory_mib"]
    print(
        f"  event streams {part['event_streams']}; memory {memory['baseline']} MiB at start, "
        f"peak {memory['peak']}, {memory['after']} after; tracebacks in the log "
        f"{part['server_tracebacks']}"
    )
    for example in part["five_xx_examples"]:
        print(f"  5xx: {example}")


def main() -> None:
    """Run the server part alone (soak.py runs it this way, in a process of its own)."""
    import argparse
    import json

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--smoke", action="store_true")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--db", default=None, help="database URL (default: a SQLite file)")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    part = soak_server(args.seconds, args.smoke, args.seed, args.db)
    if args.json:
        print(json.dumps(part))
    else:
        report(part)


if __name__ == "__main__":
    main()
