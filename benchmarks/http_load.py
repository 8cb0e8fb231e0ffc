"""Load against a running ``opendnc serve``: concurrent readers and writers, slow sockets.

Used by ``benchmarks/soak.py`` (its server part) and by the server's load tests. Every request
is timed; one that gets no answer within ``hung_after`` seconds counts as hung. Readers pace
themselves like a dashboard on a tablet (one request every ``reader_pause`` seconds on
average); writers upload new program versions and queue backup jobs, each waiting
``writer_pause`` seconds between its requests.
"""

from __future__ import annotations

import asyncio
import json
import random
import time
from collections import Counter
from dataclasses import dataclass, field
from typing import Any

import httpx

READ_PATHS = ("/api/programs", "/api/jobs?limit=20", "/api/programs/LOAD0.nc", "/api/machines")


@dataclass
class LoadResult:
    """What the clients saw."""

    statuses: Counter[int] = field(default_factory=Counter)
    latencies: list[float] = field(default_factory=list)
    by_method: dict[str, list[float]] = field(default_factory=dict)
    hung: int = 0
    errors: Counter[str] = field(default_factory=Counter)  # client-side exceptions by type
    five_xx: list[str] = field(default_factory=list)  # method, path and body of each 5xx

    @property
    def requests(self) -> int:
        """Requests that were answered."""
        return sum(self.statuses.values())

    def percentile(self, p: float) -> float:
        """The ``p``-th percentile latency in seconds (0 without answers)."""
        if not self.latencies:
            return 0.0
        ordered = sorted(self.latencies)
        return ordered[min(len(ordered) - 1, int(len(ordered) * p / 100))]

    def as_json(self) -> dict[str, Any]:
        """The figures a report prints."""
        return {
            "requests": self.requests,
            "statuses": {str(k): v for k, v in sorted(self.statuses.items())},
            "five_xx": len(self.five_xx),
            "hung": self.hung,
            "errors": dict(self.errors),
            "p50_ms": round(self.percentile(50) * 1000, 1),
            "p99_ms": round(self.percentile(99) * 1000, 1),
            "max_ms": round(max(self.latencies, default=0.0) * 1000, 1),
            "p99_ms_by_method": {
                method: round(sorted(times)[min(len(times) - 1, int(len(times) * 0.99))] * 1000, 1)
                for method, times in sorted(self.by_method.items())
            },
        }


class Connection:
    """One keep-alive HTTP/1.1 connection, spoken by hand: hundreds of these cost the load
    generator far less than a full client (with httpx the clients, not the server, were the
    bottleneck of 200 readers on two cores)."""

    def __init__(self, host: str, port: int, headers: dict[str, str]) -> None:
        self.host, self.port = host, port
        self.headers = "".join(f"{k}: {v}\r\n" for k, v in headers.items())
        self.reader: asyncio.StreamReader | None = None
        self.writer: asyncio.StreamWriter | None = None

    async def request(
        self, method: str, path: str, body: bytes = b"", ctype: str = ""
    ) -> tuple[int, bytes]:
        """Send one request and read its answer (connects, or reconnects, as needed)."""
        if self.writer is None or self.writer.is_closing():
            self.reader, self.writer = await asyncio.open_connection(self.host, self.port)
        assert self.reader is not None
        head = f"{method} {path} HTTP/1.1\r\nHost: {self.host}\r\n{self.headers}"
        if body or method in ("PUT", "POST"):
            head += f"Content-Length: {len(body)}\r\n"
        if ctype:
            head += f"Content-Type: {ctype}\r\n"
        self.writer.write(head.encode() + b"\r\n" + body)
        try:
            status_line = await self.reader.readline()
            if not status_line:
                raise ConnectionError("the server closed the connection")
            status = int(status_line.split()[1])
            length, close = 0, False
            while (line := await self.reader.readline()) not in (b"\r\n", b""):
                name, _, value = line.decode("latin-1").partition(":")
                if name.lower() == "content-length":
                    length = int(value)
                elif name.lower() == "connection" and "close" in value.lower():
                    close = True
            data = await self.reader.readexactly(length)
        except BaseException:
            self.close()
            raise
        if close:
            self.close()
        return status, data

    def close(self) -> None:
        """Drop the connection (the next request opens a new one)."""
        if self.writer is not None:
            self.writer.close()
        self.writer = None


async def timed(
    result: LoadResult,
    conn: Connection,
    method: str,
    path: str,
    *,
    hung_after: float,
    body: bytes = b"",
    ctype: str = "",
) -> int | None:
    """One request, counted in ``result``; its status, or None if it hung or failed."""
    start = time.monotonic()
    try:
        status, data = await asyncio.wait_for(conn.request(method, path, body, ctype), hung_after)
    except TimeoutError:
        result.hung += 1
        conn.close()
        return None
    except (OSError, ValueError, IndexError, asyncio.IncompleteReadError) as exc:
        result.errors[type(exc).__name__] += 1
        conn.close()
        return None
    result.latencies.append(time.monotonic() - start)
    result.by_method.setdefault(method, []).append(result.latencies[-1])
    result.statuses[status] += 1
    if status >= 500:
        result.five_xx.append(f"{method} {path[:80]}: {data[:200]!r}")
    return status


def endpoint(base_url: str) -> tuple[str, int]:
    """Host and port of ``http://HOST:PORT``."""
    url = httpx.URL(base_url)
    assert url.port is not None
    return url.host, url.port


async def readers_and_writers(
    base_url: str,
    key: str,
    *,
    seconds: float,
    readers: int = 200,
    uploaders: int = 4,
    job_makers: int = 4,
    machine: str | None = None,
    reader_pause: float = 2.0,
    writer_pause: float = 0.25,
    hung_after: float = 30.0,
    seed: int = 1,
) -> LoadResult:
    """Readers and writers for ``seconds`` against the server at ``base_url``.

    Needs the program ``LOAD0.nc`` (uploaded here first). Job makers queue backup jobs on
    ``machine`` (none without one).
    """
    result = LoadResult()
    host, port = endpoint(base_url)
    headers = {"Authorization": f"Bearer {key}"}
    rng = random.Random(seed)
    first = httpx.put(f"{base_url}/api/programs/LOAD0.nc", content=b"G0 X0\n", headers=headers)
    first.raise_for_status()
    end = time.monotonic() + seconds

    async def reader(n: int) -> None:
        local = random.Random(rng.random())
        conn = Connection(host, port, headers)
        await asyncio.sleep(local.uniform(0, reader_pause))  # not all in one instant
        while time.monotonic() < end:
            await timed(result, conn, "GET", local.choice(READ_PATHS), hung_after=hung_after)
            await asyncio.sleep(local.uniform(0.5, 1.5) * reader_pause)
        conn.close()

    async def uploader(n: int) -> None:
        conn = Connection(host, port, headers)
        version = 0
        while time.monotonic() < end:
            version += 1
            body = f"%\nO{n:04d}\nG0 X{version}\nM30\n%\n".encode()
            path = f"/api/programs/LOAD{n % 3}.nc"
            await timed(result, conn, "PUT", path, body=body, hung_after=hung_after)
            await asyncio.sleep(writer_pause)
        conn.close()

    async def job_maker(n: int) -> None:
        conn = Connection(host, port, headers)
        body = json.dumps({"kind": "backup", "path": f"TNC:/LOAD{n}.H", "machines": [machine]})
        while time.monotonic() < end and machine is not None:
            await timed(
                result,
                conn,
                "POST",
                "/api/jobs",
                body=body.encode(),
                ctype="application/json",
                hung_after=hung_after,
            )
            await asyncio.sleep(writer_pause)
        conn.close()

    await asyncio.gather(
        *(reader(i) for i in range(readers)),
        *(uploader(i) for i in range(uploaders)),
        *(job_maker(i) for i in range(job_makers)),
    )
    return result
