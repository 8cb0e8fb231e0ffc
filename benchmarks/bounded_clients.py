"""Clients that hold the server without reading: large downloads and idle event streams.

Against ``opendnc serve`` on loopback (docs/server.md#bounded-clients):

* **downloads**: 12 clients ask for a 64 MB program version and never read a byte. Prints the
  server's memory (RSS) before, at its peak while they hang there, and after, and how long
  the server took to cut each of them (its ``send_timeout``, 10 s here).
* **streams**: 1,200 event streams (``/api/events``) are opened and left idle (the clients
  read nothing; the heartbeats sit in their socket buffers), then a normal GET
  (``/api/machines``) is timed 300 times one after another. Prints its p50, p99 and max, the
  server's CPU use while the streams idle, and the answers the streams got (a 503 beyond the
  cap says the cap works; the benchmark raises the caps to 1,300 so that 1,200 open).

Bounded: at most 1,212 connections, about two minutes in all. Loopback only.

    .venv/bin/python benchmarks/bounded_clients.py
    .venv/bin/python benchmarks/bounded_clients.py --part streams --streams 600
"""

from __future__ import annotations

import argparse
import asyncio
import resource
import socket
import statistics
import tempfile
import time
from collections import Counter
from pathlib import Path

import httpx

from served import cpu_seconds, rss_mib, start_serve, stop_serve

BIG = 64 * 1000 * 1000


def _port(url: str) -> int:
    return int(url.rsplit(":", 1)[1])


def _quiet_socket(port: int) -> socket.socket:
    # A client that reads nothing: a small receive buffer, so the server's writes back up
    # into its own memory instead of the kernel's.
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    sock.connect(("127.0.0.1", port))
    return sock


def _closed(sock: socket.socket) -> bool:
    """True once the server closed or reset ``sock``, asked of the kernel without reading
    (a read would make room for more: the client would be reading after all)."""
    info = sock.getsockopt(socket.IPPROTO_TCP, socket.TCP_INFO, 8)
    return info[0] != 1  # 1: TCP_ESTABLISHED


def downloads(url: str, key: str, pid: int, count: int, send_timeout: float) -> None:
    """``count`` clients that never read a 64 MB download."""
    line = b"G01 X123.456 Y-78.901 Z-1.000 F1200.\n"
    body = line * (BIG // len(line))
    with httpx.Client(base_url=url, timeout=120) as http:
        put = http.put(
            "/api/programs/BIG.nc", content=body, headers={"Authorization": f"Bearer {key}"}
        )
        put.raise_for_status()
    del body
    time.sleep(2)
    before = rss_mib(pid)
    request = (
        f"GET /api/programs/BIG.nc/versions/1/content HTTP/1.1\r\nHost: x\r\n"
        f"Authorization: Bearer {key}\r\n\r\n"
    ).encode()
    socks = []
    opened = time.monotonic()
    for _ in range(count):
        sock = _quiet_socket(_port(url))
        sock.sendall(request)
        socks.append(sock)
    peak = before
    cut_after: list[float] = []
    deadline = opened + send_timeout + 30
    while time.monotonic() < deadline and len(cut_after) < count:
        peak = max(peak, rss_mib(pid))
        for sock in socks:
            if sock.fileno() >= 0 and _closed(sock):
                cut_after.append(time.monotonic() - opened)
                sock.close()
        time.sleep(0.2)
    for sock in socks:
        sock.close()
    time.sleep(2)
    after = rss_mib(pid)
    print(
        f"downloads: {count} non-reading clients of a {BIG / 1e6:.0f} MB version: RSS "
        f"{before:.0f} MiB before, peak {peak:.0f} MiB (+{peak - before:.0f}), "
        f"{after:.0f} MiB after"
    )
    if cut_after:
        print(
            f"  cut by the server: {len(cut_after)} of {count}, after "
            f"{min(cut_after):.1f}-{max(cut_after):.1f} s (send_timeout {send_timeout:g} s)"
        )
    else:
        print(f"  cut by the server: none within {send_timeout + 30:.0f} s")


async def _open_streams(
    port: int, key: str, count: int
) -> tuple[list[socket.socket], Counter[str]]:
    request = (
        f"GET /api/events HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer {key}\r\n\r\n"
    ).encode()
    statuses: Counter[str] = Counter()
    writers = []
    gate = asyncio.Semaphore(50)  # connect 50 at a time: a burst of 1,200 at once is a test of
    # the accept queue, not of idle streams

    async def one() -> None:
        async with gate:
            try:
                reader, writer = await asyncio.open_connection("127.0.0.1", port)
                writer.write(request)
                status = await asyncio.wait_for(reader.readline(), 30)
                statuses[status[9:12].decode("latin-1") or "closed"] += 1
                writers.append(writer)
            except (OSError, TimeoutError) as exc:
                statuses[type(exc).__name__] += 1

    await asyncio.gather(*(one() for _ in range(count)))
    # the loop ends with this function: duplicates of the sockets keep the streams open
    socks = [w.get_extra_info("socket").dup() for w in writers]
    return socks, statuses


def streams(url: str, key: str, pid: int, count: int, gets: int) -> None:
    """``count`` idle event streams, and a normal GET timed ``gets`` times meanwhile."""
    socks, statuses = asyncio.run(_open_streams(_port(url), key, count))
    time.sleep(3)  # let the streams settle into idling
    cpu0, wall0 = cpu_seconds(pid), time.monotonic()
    time.sleep(10)
    idle_cpu = (cpu_seconds(pid) - cpu0) / (time.monotonic() - wall0) * 100
    times = []
    print(f"  ({count} streams open; timing GETs)", flush=True)
    with httpx.Client(base_url=url, timeout=30, headers={"Authorization": f"Bearer {key}"}) as h:
        h.get("/api/machines").raise_for_status()
        for _ in range(gets):
            started = time.perf_counter()
            h.get("/api/machines").raise_for_status()
            times.append(time.perf_counter() - started)
        stalls = h.get("/api/health/loop").json().get("recent_stalls", [])
    times.sort()
    p99 = times[min(len(times) - 1, int(len(times) * 0.99))]
    worst = sorted(stalls, key=lambda st: -st["seconds"])[:3]
    shown = ", ".join(f"{st['seconds'] * 1000:.0f} ms (ran {st['run'] * 1000:.0f})" for st in worst)
    print(f"  the loop's longest recent stalls: {shown or 'none'}")
    print(
        f"streams: {count} opened ({dict(statuses)}); server CPU while they idle "
        f"{idle_cpu:.0f} % of a core; GET /api/machines x{gets}: p50 "
        f"{statistics.median(times) * 1000:.1f} ms, p99 {p99 * 1000:.1f} ms, max "
        f"{times[-1] * 1000:.1f} ms; server RSS {rss_mib(pid):.0f} MiB"
    )
    for sock in socks:
        sock.close()


def main() -> None:
    """Run the parts asked for and print their figures."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--part", choices=["all", "downloads", "streams"], default="all")
    parser.add_argument("--downloads", type=int, default=12)
    parser.add_argument("--streams", type=int, default=1200)
    parser.add_argument("--gets", type=int, default=300)
    parser.add_argument("--send-timeout", type=float, default=10.0)
    parser.add_argument(
        "--no-clients-table", action="store_true", help="for a server older than [clients]"
    )
    args = parser.parse_args()
    args.streams = min(args.streams, 1200)
    args.downloads = min(args.downloads, 12)
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    resource.setrlimit(resource.RLIMIT_NOFILE, (max(soft, min(hard, 8192)), hard))
    clients = f"send_timeout = {args.send_timeout}\nstreams_per_user = 1300\nstreams_total = 1300"
    if args.no_clients_table:
        clients = ""
    with tempfile.TemporaryDirectory(prefix="opendnc-bounded-") as folder:
        proc, url, key = start_serve(Path(folder), clients=clients)
        try:
            if args.part in ("all", "downloads"):
                downloads(url, key, proc.pid, args.downloads, args.send_timeout)
            if args.part in ("all", "streams"):
                streams(url, key, proc.pid, args.streams, args.gets)
        finally:
            stop_serve(proc)


if __name__ == "__main__":
    main()
