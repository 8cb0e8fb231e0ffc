"""How long the server's event loop was kept from running its tasks, and why.

Every task of the server (machine polls, transfers, the live streams of the dashboard) runs
on one asyncio loop; while a callback holds it, nothing else moves. A small task sleeps
:data:`INTERVAL` seconds at a time and measures how late it wakes: that lateness is a *stall*
(docs/server.md#event-loop-stalls). Each stall is split into what the loop's own thread did
meanwhile:

- ``run``: CPU time of the loop's thread (server code holding the loop);
- ``wait``: time the thread was ready to run but waited for a CPU (other processes, or the
  server's worker threads, had the cores); Linux only (``/proc/thread-self/schedstat``);
- the rest: the thread slept while it should have run (a blocking call on the loop, or the
  interpreter lock held by a worker thread).

``GET /api/health`` shows the longest stalls since the start and every stall of the last
:data:`RECENT` seconds (the benchmarks read them); a stall of :data:`WARN` seconds or more
is logged.
"""

from __future__ import annotations

import asyncio
import heapq
import logging
import time
from collections import deque
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from opendnc.server.core.components import RunsTask

__all__ = ["INTERVAL", "WARN", "LoopWatch", "Stall"]

log = logging.getLogger(__name__)

INTERVAL = 0.05  # how often the watch wakes (s)
WARN = 1.0  # stalls this long are logged (s)
KEEP = 20  # the longest stalls kept
RECENT = 60.0  # every stall of the last this many seconds is kept (s)
SCHEDSTAT = Path("/proc/thread-self/schedstat")


@dataclass(frozen=True, order=True)
class Stall:
    """One late wake-up of the loop: ``seconds`` late, of which ``run`` seconds the loop's
    thread ran and ``wait`` seconds it waited for a CPU (None where unknown)."""

    seconds: float
    at: datetime
    run: float
    wait: float | None

    def as_json(self) -> dict[str, Any]:
        """JSON-ready (seconds rounded to the millisecond)."""
        return {
            "at": self.at.isoformat(),
            "seconds": round(self.seconds, 3),
            "run": round(self.run, 3),
            "wait": None if self.wait is None else round(self.wait, 3),
        }


def _runqueue_wait() -> float | None:
    # Second field of schedstat: nanoseconds this thread spent runnable, waiting for a CPU.
    try:
        return int(SCHEDSTAT.read_text().split()[1]) / 1e9
    except (OSError, IndexError, ValueError):
        return None


class LoopWatch(RunsTask):
    """Measures the loop's stalls while :meth:`run` runs on it."""

    name = "loop-watch"

    def __init__(self, interval: float = INTERVAL, warn: float = WARN) -> None:
        self.interval = interval
        self.warn = warn
        self.started: datetime | None = None
        self.wakes = 0
        self._longest: list[Stall] = []  # a min-heap of the KEEP longest
        self._recent: deque[tuple[float, Stall]] = deque()  # (loop time, stall)

    async def run(self) -> None:
        """Watch until cancelled."""
        loop = asyncio.get_running_loop()
        self.started = datetime.now(UTC)
        while True:
            t0, cpu0, wait0 = loop.time(), time.thread_time(), _runqueue_wait()
            await asyncio.sleep(self.interval)
            late = loop.time() - t0 - self.interval
            self.wakes += 1
            if late < self.interval:
                continue  # timer granularity and an ordinary busy moment
            wait1 = _runqueue_wait()
            wait = None if wait0 is None or wait1 is None else max(0.0, wait1 - wait0)
            # Both counters cover the sleep too: at most `late` of each belongs to the stall.
            stall = Stall(
                late,
                datetime.now(UTC),
                min(late, time.thread_time() - cpu0),
                None if wait is None else min(late, wait),
            )
            now = loop.time()
            self._recent.append((now, stall))
            while self._recent[0][0] < now - RECENT:
                self._recent.popleft()
            if len(self._longest) < KEEP:
                heapq.heappush(self._longest, stall)
            else:
                heapq.heappushpop(self._longest, stall)
            if late >= self.warn:
                log.warning(
                    "the event loop stalled %.2f s (its thread ran %.2f s, waited for a CPU %s)",
                    late,
                    stall.run,
                    "?" if stall.wait is None else f"{stall.wait:.2f} s",
                )

    def longest(self) -> list[Stall]:
        """The longest stalls seen, longest first."""
        return sorted(self._longest, reverse=True)

    def as_json(self) -> dict[str, Any]:
        """What ``/api/health`` shows."""
        return {
            "since": self.started.isoformat() if self.started else None,
            "interval": self.interval,
            "longest_stalls": [s.as_json() for s in self.longest()],
            "recent_stalls": [s.as_json() for _, s in self._recent],
        }
