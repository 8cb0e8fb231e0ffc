"""A heartbeat in the dashboard's event streams, so a page can tell a quiet stream from a dead
one (docs/dashboard.md#live-overview).

A stream that has nothing to say sends nothing; a server that stopped, or a network that
went silent, looks the same from the browser. Every :data:`HEARTBEAT` seconds each dashboard
stream sends a ``heartbeat`` event carrying the server's time and the shop's zone label; the
page (static/live.js) greys itself and says since when once it has heard nothing for a few
heartbeats, or at once when the browser reports the stream broken, and reconnects by itself.

The comment streams.py sends to keep proxies open is invisible to a page's script (the
browser's EventSource drops comments), hence a named event here.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from datetime import UTC, datetime, tzinfo

from opendnc.server.core.events import Event
from opendnc.server.http.streams import StreamSource
from opendnc.server.web.render import sse_event, zone_label

__all__ = ["HEARTBEAT", "Heartbeat", "heartbeat_event"]

HEARTBEAT = 2.0
"""Seconds between heartbeats (the page counts a stream lost after 5 s without one)."""


def heartbeat_event(zone: tzinfo, at: datetime | None = None) -> bytes:
    """One ``heartbeat`` event: the server's time (UTC, ISO 8601) and the shop's zone label
    at that time (``CET``, ``CEST``), which the wall clock shows."""
    at = at or datetime.now(UTC)
    data = {"at": at.isoformat(timespec="seconds"), "zone": zone_label(at, zone)}
    return sse_event("heartbeat", json.dumps(data, separators=(",", ":")))


class Heartbeat:
    """``source`` with a heartbeat event at least every ``every`` seconds (checked at each
    flush, which the stream loop calls at its interval whether or not events came)."""

    def __init__(
        self,
        source: StreamSource,
        zone: tzinfo,
        every: float = HEARTBEAT,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.source = source
        self.zone = zone
        self.every = every
        self.clock = clock
        self.last = clock()

    async def snapshot(self, overflow: bool) -> bytes:
        """The source's snapshot; the flush that follows it carries a first heartbeat, after
        what the source sends (the page knows the zone at once, and reads its own first)."""
        self.last = float("-inf")
        return await self.source.snapshot(overflow)

    def take(self, event: Event) -> None:
        """Fold ``event`` into the source."""
        self.source.take(event)

    async def flush(self) -> bytes:
        """The source's pending changes, and a heartbeat when one is due."""
        out = await self.source.flush()
        now = self.clock()
        if now - self.last >= self.every:
            self.last = now
            out += heartbeat_event(self.zone)
        return out
