"""One loop for every server-sent-events stream: the API's events, the dashboard's live cards
and its live lists (docs/server.md#events-and-states).

A stream subscribes to the event bus, sends a snapshot as it opens, then folds the events
that arrive into what it will send and flushes that at most every ``interval`` seconds
(a status poll that changed nothing, or a thousand progress reports a second, never reach the
browser one by one). After ``keep_alive`` quiet seconds it sends a comment, so a proxy keeps
the connection and the server notices a client that went away. A subscriber that fell behind
lost events: it sends a fresh snapshot instead of guessing. The stream ends when the client
disconnects or its task is cancelled, and unsubscribes either way.

What a stream sends is its :class:`StreamSource`'s business; the timing is only here.
"""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator, Awaitable, Callable
from typing import Protocol

from starlette.requests import Request
from starlette.responses import StreamingResponse

from opendnc.server.events import Event, EventBus

__all__ = [
    "KEEP_ALIVE",
    "KEEP_ALIVE_COMMENT",
    "StreamSource",
    "event_stream_response",
    "throttled_stream",
]

KEEP_ALIVE = 15.0
"""Seconds without a message after which a stream sends a comment."""

KEEP_ALIVE_COMMENT = b": keep-alive\n\n"


class StreamSource(Protocol):
    """What one stream sends: a snapshot, and the changes folded from events."""

    async def snapshot(self, overflow: bool) -> bytes:
        """Bytes to send as the stream opens (``overflow`` False) or after events were lost
        (True); may instead mark everything pending for the next :meth:`flush`."""

    def take(self, event: Event) -> None:
        """Fold one event into what the next :meth:`flush` sends."""

    async def flush(self) -> bytes:
        """What is pending, as server-sent events (empty when nothing is)."""


async def throttled_stream(
    bus: EventBus,
    source: StreamSource,
    *,
    interval: float,
    disconnected: Callable[[], Awaitable[bool]],
    keep_alive: float = KEEP_ALIVE,
    maxsize: int = 1000,
) -> AsyncIterator[bytes]:
    """Server-sent events from ``source``: a snapshot, then at most one flush per
    ``interval`` while events arrive, a keep-alive comment after ``keep_alive`` quiet
    seconds; until ``disconnected()`` says so or the task is cancelled."""
    loop = asyncio.get_running_loop()
    with bus.subscribe(maxsize) as sub:
        out = await source.snapshot(False) + await source.flush()
        if out:
            yield out
        quiet_since = loop.time()
        flush_at = quiet_since + interval
        while not await disconnected():
            event = await sub.get(max(0.0, flush_at - loop.time()))
            if event is not None:
                # The first event, then everything queued meanwhile, in one go: a wait per
                # event costs the loop more than the event while hundreds of transfers run.
                source.take(event)
                for later in sub.drain():
                    source.take(later)
                if loop.time() < flush_at:
                    continue  # a steady stream of events must not hold the flush back either
            out = await source.snapshot(True) if sub.take_overflow() else b""
            out += await source.flush()
            now = loop.time()
            if out:
                quiet_since = now
                yield out
            elif now - quiet_since >= keep_alive:
                quiet_since = now
                yield KEEP_ALIVE_COMMENT
            flush_at = loop.time() + interval


def event_stream_response(
    request: Request, bus: EventBus, source: StreamSource, *, interval: float
) -> StreamingResponse:
    """The response of a route that streams ``source``: until the client goes away, never
    cached, and not buffered by a proxy in front of the server (nginx honours the header)."""
    stream = throttled_stream(bus, source, interval=interval, disconnected=request.is_disconnected)
    return StreamingResponse(
        stream,
        media_type="text/event-stream",
        headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"},
    )
