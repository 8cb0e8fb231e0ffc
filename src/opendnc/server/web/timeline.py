"""Each machine's recent states (connection, mode, execution), for the status timeline.

A recorder listens to the server's event bus for as long as the app runs and keeps, per
machine, the moments its state changed over the last :data:`KEEP_HOURS` (in memory: the
timeline starts again when the server does). The machine page draws it as an SVG strip.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections import deque
from dataclasses import dataclass
from datetime import datetime, timedelta
from typing import Any

from opendnc.server.events import EventBus
from opendnc.server.store.models import utcnow

__all__ = ["Segment", "Timeline"]

KEEP_HOURS = 8
MAX_CHANGES = 5000  # per machine: a control that flips state every second still fits hours


@dataclass(frozen=True)
class Segment:
    """One stretch of time in one state, placed on a strip ``width`` wide."""

    x: float
    width: float
    state: str  # offline, active, ready, stopped, alarm
    label: str


def _state(machine: dict[str, Any]) -> tuple[str, str]:
    status = machine.get("status") or {}
    if not machine.get("online"):
        return "offline", "offline"
    execution = str(status.get("execution") or "")
    mode = str(status.get("mode") or "").replace("_", " ").lower()
    if status.get("errors"):
        kind = "alarm"
    elif execution == "ACTIVE":
        kind = "active"
    elif execution in ("STOPPED", "INTERRUPTED", "FEED_HOLD"):
        kind = "stopped"
    else:
        kind = "ready"
    label = f"{execution.replace('_', ' ').lower() or 'ready'}{', ' + mode if mode else ''}"
    return kind, label


class Timeline:
    """State changes per machine, fed from the event bus."""

    def __init__(self) -> None:
        self.changes: dict[str, deque[tuple[datetime, str, str]]] = {}

    def note(self, name: str, machine: dict[str, Any], at: datetime | None = None) -> None:
        """Record the machine's state if it differs from the last one recorded."""
        kind, label = _state(machine)
        history = self.changes.setdefault(name, deque(maxlen=MAX_CHANGES))
        if history and history[-1][1:] == (kind, label):
            return
        history.append((at or utcnow(), kind, label))

    async def record(self, bus: EventBus) -> None:
        """Listen until cancelled."""
        with bus.subscribe(maxsize=10_000) as sub:
            while True:
                event = await sub.get()
                if event.kind == "machine":
                    self.note(event.key, event.data)

    def segments(
        self, name: str, *, hours: float = 4.0, width: float = 1000.0, now: datetime | None = None
    ) -> list[Segment]:
        """The last ``hours`` of ``name`` as segments of a strip ``width`` wide."""
        now = now or utcnow()
        start = now - timedelta(hours=hours)
        span = (now - start).total_seconds()
        history = list(self.changes.get(name, ()))
        out: list[Segment] = []
        for i, (at, kind, label) in enumerate(history):
            until = history[i + 1][0] if i + 1 < len(history) else now
            if until <= start:
                continue
            begin = max(at, start)
            x = (begin - start).total_seconds() / span * width
            w = (until - begin).total_seconds() / span * width
            out.append(Segment(round(x, 2), round(max(w, 0.5), 2), kind, label))
        return out


@contextlib.asynccontextmanager
async def running(timeline: Timeline, bus: EventBus) -> Any:
    """Run the recorder for the duration of the ``async with`` block."""
    task = asyncio.create_task(timeline.record(bus), name="status-timeline")
    try:
        yield
    finally:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task
