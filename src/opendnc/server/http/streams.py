"""One loop for every server-sent-events stream: the API's events, the dashboard's live cards
and its live lists (docs/server.md#events-and-states, #bounded-clients).

A stream subscribes to the event bus, sends a snapshot as it opens, then folds the events
that arrive into what it will send and flushes that at most every ``interval`` seconds
(a status poll that changed nothing, or a thousand progress reports a second, never reach the
browser one by one). After ``keep_alive`` quiet seconds (the ``[clients] heartbeat``) it sends
a comment, so a page sees its stream is alive, a proxy keeps the connection and a client that
stopped reading is noticed (the send timeout cuts it, :mod:`opendnc.server.http.clients`). After
``idle`` seconds of nothing but comments it ends; the browser reconnects and gets a snapshot.
A subscriber that fell behind lost events: it sends a fresh snapshot instead of guessing.

An idle stream sleeps until an event or its next heartbeat, nothing else. It used to wake
every ``interval`` (0.5 s) to ask whether its client had gone (Starlette's
``is_disconnected``, a cancelled receive each time): 1,200 idle streams were 4,800 wake-ups
and 2,400 such probes a second, most of the server's CPU, and a normal request waited behind
them (p99 0.4 s). The response's own disconnect listener ends the stream when the client goes.

The stream ends when the client disconnects or its task is cancelled, and unsubscribes either
way. What a stream sends is its :class:`StreamSource`'s business; the timing is only here.
"""

from __future__ import annotations

import asyncio
import math
import random
from collections.abc import AsyncIterator, Awaitable, Callable
from typing import Protocol

from starlette.requests import Request
from starlette.responses import StreamingResponse
from starlette.types import Receive, Scope, Send

from opendnc.server.config.clients import ClientLimits
from opendnc.server.core.components import core_of
from opendnc.server.core.events import Event, EventBus
from opendnc.server.http.clients import Clients

__all__ = [
    "KEEP_ALIVE",
    "KEEP_ALIVE_COMMENT",
    "StreamSource",
    "event_stream_response",
    "throttled_stream",
]

KEEP_ALIVE = ClientLimits.heartbeat
"""Seconds without a message after which a stream sends a comment (the default of
``[clients] heartbeat``)."""

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
    disconnected: Callable[[], Awaitable[bool]] | None = None,
    keep_alive: float = KEEP_ALIVE,
    idle: float | None = None,
    maxsize: int = 1000,
    beat: Callable[[], bytes] | None = None,
) -> AsyncIterator[bytes]:
    """Server-sent events from ``source``: a snapshot, then at most one flush per
    ``interval`` while events arrive, a keep-alive comment after ``keep_alive`` quiet
    seconds; until ``idle`` seconds pass with nothing but comments, ``disconnected()`` (asked
    only when the stream wakes anyway, never polled) says so, or the task is cancelled.

    ``beat`` makes the keep-alive a message a page's script sees (a named event: a browser's
    EventSource drops comments), so the page can tell a quiet stream from a dead one; like the
    comment it does not count as saying something, so an idle stream still ends."""
    loop = asyncio.get_running_loop()
    with bus.subscribe(maxsize) as sub:
        out = await source.snapshot(False) + await source.flush()
        if out:
            yield out
        flushed = loop.time()  # the last flush
        said = flushed  # the last message that was not a comment
        # The last message of any kind, set back by a random part of a heartbeat: streams
        # opened together (every page reconnecting after a restart) then do not all send
        # their heartbeats in the same turn of the loop, which a request would wait behind.
        sent = flushed - keep_alive * random.uniform(0.0, 0.25)
        ends = said + idle if idle is not None else math.inf
        while disconnected is None or not await disconnected():
            now = loop.time()
            if now >= ends:
                return
            # asleep until an event, the next comment or the idle end: nothing to poll
            event = await sub.get(max(0.0, min(sent + keep_alive, ends) - now))
            if event is None:
                now = loop.time()
                if now - sent >= keep_alive and now < ends:
                    sent = now
                    yield beat() if beat is not None else KEEP_ALIVE_COMMENT
                continue
            # The first event, then everything queued meanwhile, in one go: a wait per
            # event costs the loop more than the event while hundreds of transfers run. Until
            # the next flush is due the stream takes what comes (a full subscription would
            # lose events), then flushes once.
            while event is not None:
                source.take(event)
                for later in sub.drain():
                    source.take(later)
                wait = flushed + interval - loop.time()
                event = await sub.get(wait) if wait > 0 else None
            out = await source.snapshot(True) if sub.take_overflow() else b""
            out += await source.flush()
            flushed = loop.time()
            if out:  # a flush with nothing new (a poll that changed nothing) is not a message
                sent = said = flushed
                ends = said + idle if idle is not None else math.inf
                yield out


class _SlotResponse(StreamingResponse):
    """A streaming response that gives its stream slot back however it ends (the body's
    generator may never start when the client is gone at once)."""

    def __init__(self, content: AsyncIterator[bytes], give_back: Callable[[], None]) -> None:
        super().__init__(
            content,
            media_type="text/event-stream",
            headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"},
        )
        self.give_back = give_back

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        try:
            await super().__call__(scope, receive, send)
        finally:
            self.give_back()


def event_stream_response(
    request: Request,
    bus: EventBus,
    source: StreamSource,
    *,
    interval: float,
    who: str | None = None,
    beat: Callable[[], bytes] | None = None,
    keep_alive: float | None = None,
) -> StreamingResponse:
    """The response of a route that streams ``source``: until the client goes away, never
    cached, and not buffered by a proxy in front of the server (nginx honours the header).

    ``who`` (the user) takes one of the server's stream slots; beyond its caps the route is
    refused with :class:`opendnc.server.http.clients.StreamsFull` (503, ``Retry-After``). ``beat``
    and ``keep_alive`` (at most ``[clients] heartbeat``) are :func:`throttled_stream`'s: the
    dashboard's pages need a heartbeat they can see, every 2 s."""
    clients = core_of(request.app).find(Clients)
    limits = clients.limits if clients is not None else ClientLimits()
    give_back = clients.slots.take(who or "?") if clients is not None else (lambda: None)
    every = limits.heartbeat if keep_alive is None else min(keep_alive, limits.heartbeat)
    stream = throttled_stream(
        bus, source, interval=interval, keep_alive=every, idle=limits.stream_idle, beat=beat
    )
    return _SlotResponse(stream, give_back)
