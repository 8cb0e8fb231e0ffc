"""An in-process event bus: status changes, job progress, programs received.

The API's server-sent events, the MQTT publisher and the MTConnect adapter are subscribers
like any other (docs/server.md#open-outputs).
A subscriber that falls behind loses its oldest events rather than slowing the machines down;
it is told so by an ``overflow`` event and can ask for a fresh snapshot.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

__all__ = ["Event", "EventBus", "Subscription", "on_loop"]


@dataclass(frozen=True)
class Event:
    """Something that happened: ``kind`` (``status``, ``job``, ...), a key and JSON data."""

    kind: str
    key: str
    data: dict[str, Any] = field(default_factory=dict)


class Subscription:
    """A bounded queue of events for one listener."""

    def __init__(self, maxsize: int) -> None:
        self.queue: asyncio.Queue[Event] = asyncio.Queue(maxsize)
        self.overflowed = False

    def put(self, event: Event) -> None:
        """Queue ``event``, dropping the oldest one when full."""
        if self.queue.full():
            self.overflowed = True
            with contextlib.suppress(asyncio.QueueEmpty):
                self.queue.get_nowait()
        self.queue.put_nowait(event)

    async def get(self) -> Event:
        """The next event."""
        return await self.queue.get()

    def drain(self) -> list[Event]:
        """Every event queued now, without waiting (oldest first)."""
        out = []
        while not self.queue.empty():
            out.append(self.queue.get_nowait())
        return out


class EventBus:
    """Fan-out of events to every subscriber, on the event loop's thread."""

    def __init__(self) -> None:
        self._subscribers: set[Subscription] = set()
        self._loop: asyncio.AbstractEventLoop | None = None

    def bind(self, loop: asyncio.AbstractEventLoop) -> None:
        """Remember the loop, so worker threads can publish safely."""
        self._loop = loop

    @contextlib.contextmanager
    def subscribe(self, maxsize: int = 1000) -> Iterator[Subscription]:
        """Receive events for as long as the ``with`` block lasts."""
        sub = Subscription(maxsize)
        self._subscribers.add(sub)
        try:
            yield sub
        finally:
            self._subscribers.discard(sub)

    def publish(self, kind: str, key: str, data: dict[str, Any]) -> None:
        """Deliver an event to every subscriber (callable from any thread)."""
        event = Event(kind, key, data)
        loop = self._loop
        if loop is not None and not on_loop(loop):
            loop.call_soon_threadsafe(self._deliver, event)
        else:
            self._deliver(event)

    def _deliver(self, event: Event) -> None:
        for sub in list(self._subscribers):
            sub.put(event)


def on_loop(loop: asyncio.AbstractEventLoop) -> bool:
    """True when called on ``loop``'s own thread (while it runs)."""
    try:
        return asyncio.get_running_loop() is loop
    except RuntimeError:
        return False
