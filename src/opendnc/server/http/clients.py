"""Bounded clients: a response's client must keep reading, and event streams are counted
(docs/server.md#bounded-clients).

A tester once started twelve 64 MB downloads and read none of them: the server held every
body (its memory went from 243 MB to over 1 GB) for as long as the clients stayed. And 1,200
idle event streams took the server from 2 % to 65 % CPU. Three guards:

* :class:`SendTimeout` (ASGI middleware, outermost) gives every piece of every response
  :attr:`ClientLimits.send_timeout` seconds to be taken by the client. A large body is handed
  on in pieces of :data:`CHUNK` bytes, so the deadline measures progress, not the whole
  transfer: a slow line that reads goes on, a client that stops reading is cut (its
  connection aborted, whatever it held freed). Large downloads are streamed from the
  database in such pieces (:mod:`opendnc.server.http.downloads`), so a client that does not read
  holds one piece, not the whole program, until it is cut.
* :class:`StreamSlots` counts the open event streams per user and in total; one beyond
  either cap is refused with 503 and ``Retry-After`` (:class:`StreamsFull`).
* The streams themselves (:mod:`opendnc.server.http.streams`) send a heartbeat comment every
  :attr:`ClientLimits.heartbeat` seconds, end after :attr:`ClientLimits.stream_idle` seconds
  of nothing but heartbeats (the browser reconnects and gets a fresh snapshot), and no
  longer wake up to poll when nothing happens.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import socket
import struct
import threading
from collections.abc import Callable
from typing import Any

from starlette.types import ASGIApp, Message, Receive, Scope, Send

from opendnc.server.config.clients import ClientLimits
from opendnc.server.core.errors import Unavailable

__all__ = [
    "CHUNK",
    "ClientLimits",
    "ClientTooSlow",
    "Clients",
    "SendTimeout",
    "StreamSlots",
    "StreamsFull",
]

log = logging.getLogger(__name__)

CHUNK = 256 * 1024  # bytes handed to the connection at a time
RETRY_AFTER = 15  # seconds a refused stream is told to wait


class ClientTooSlow(Exception):
    """A client did not take a piece of its response in time (its connection is aborted)."""


class StreamsFull(Unavailable):
    """No event stream slot is free for this user or on this server (HTTP 503)."""

    def __init__(self, message: str, retry_after: int = RETRY_AFTER) -> None:
        super().__init__(message)
        self.retry_after = retry_after


class StreamSlots:
    """The event streams open now, per user and in total, under :class:`ClientLimits` caps."""

    def __init__(self, limits: ClientLimits) -> None:
        self.limits = limits
        self.total = 0
        self._users: dict[str, int] = {}
        self._lock = threading.Lock()  # taken on the loop; released from wherever a stream ends

    def take(self, user: str) -> Callable[[], None]:
        """A slot for ``user``'s stream, and the function that gives it back (call it once);
        :class:`StreamsFull` when the user or the server is at its cap."""
        with self._lock:
            held = self._users.get(user, 0)
            if held >= self.limits.streams_per_user:
                raise StreamsFull(
                    f"{user} has {held} event streams open, the most one user may; close a "
                    "page or try again later"
                )
            if self.total >= self.limits.streams_total:
                raise StreamsFull(
                    f"the server has {self.total} event streams open, its limit; try again later"
                )
            self._users[user] = held + 1
            self.total += 1
        given_back = False

        def give_back() -> None:
            nonlocal given_back
            with self._lock:
                if given_back:
                    return
                given_back = True
                self.total -= 1
                left = self._users[user] - 1
                if left:
                    self._users[user] = left
                else:
                    del self._users[user]

        return give_back

    def held(self, user: str) -> int:
        """Streams ``user`` holds open now."""
        with self._lock:
            return self._users.get(user, 0)


class Clients:
    """The server's client limits and its stream slots (a component with nothing to run)."""

    name = "clients"
    needs: tuple[str, ...] = ()

    def __init__(self, limits: ClientLimits | None = None) -> None:
        self.limits = limits or ClientLimits()
        self.slots = StreamSlots(self.limits)

    async def start(self) -> None:
        """Nothing to start."""

    async def stop(self) -> None:
        """Nothing to stop: the streams end with their connections."""


def _aborter(receive: Receive) -> Callable[[], None] | None:
    """How to abort the connection a request came on, if its server lets us: uvicorn's
    ``receive`` (what the outermost middleware gets) is a method of its request cycle, which
    holds the connection's transport. ASGI itself has no way to abort a connection."""
    transport: Any = getattr(getattr(receive, "__self__", None), "transport", None)
    if not callable(getattr(transport, "abort", None)):
        return None

    def abort() -> None:
        # A zero linger time makes the close a reset: without it the kernel keeps the bytes
        # not sent yet, and the connection, until the client reads them (it never will).
        sock = transport.get_extra_info("socket")
        if sock is not None:
            with contextlib.suppress(OSError):
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, _NO_LINGER)
        transport.abort()

    return abort


# struct linger: two ints on POSIX, two unsigned shorts on Windows
_NO_LINGER = struct.pack("HH" if os.name == "nt" else "ii", 1, 0)


class SendTimeout:
    """Cut a client that does not take its response (see the module); ``limits`` is a
    callable so that the server's configuration, known once it is built, decides."""

    def __init__(self, app: ASGIApp, limits: Callable[[], ClientLimits] = ClientLimits) -> None:
        self.app = app
        self.limits = limits

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        timeout = self.limits().send_timeout
        abort = _aborter(receive)
        cut = False

        async def one(message: Message) -> None:
            nonlocal cut
            if cut:
                raise ClientTooSlow("the client was cut")
            try:
                async with asyncio.timeout(timeout):
                    await send(message)
            except TimeoutError:
                cut = True
                if abort is not None:
                    abort()  # its buffered bytes go with it
                raise ClientTooSlow(
                    f"the client took nothing of its response for {timeout:g} s"
                ) from None

        async def timed_send(message: Message) -> None:
            body = message.get("body", b"")
            if message["type"] != "http.response.body" or len(body) <= CHUNK:
                await one(message)
                return
            more = message.get("more_body", False)
            view = memoryview(body)
            for start in range(0, len(view), CHUNK):
                last = start + CHUNK >= len(view)
                piece = bytes(view[start : start + CHUNK])
                await one(
                    {"type": "http.response.body", "body": piece, "more_body": more or not last}
                )

        try:
            await self.app(scope, receive, timed_send)
        except BaseException as exc:
            if not cut or not _only_too_slow(exc):
                raise
            log.info("%s %s: %s", scope.get("method"), scope.get("path"), _first_too_slow(exc))
            # the abort's connection_lost runs on the next turn of the loop: uvicorn then
            # knows the client is gone and does not complain of an unfinished response
            for _ in range(3):
                await asyncio.sleep(0)


def _only_too_slow(exc: BaseException) -> bool:
    if isinstance(exc, ClientTooSlow):
        return True
    if isinstance(exc, BaseExceptionGroup):
        return all(
            _only_too_slow(e) or isinstance(e, asyncio.CancelledError) for e in exc.exceptions
        )
    return False


def _first_too_slow(exc: BaseException) -> BaseException:
    if isinstance(exc, BaseExceptionGroup):
        for inner in exc.exceptions:
            if _only_too_slow(inner):
                return _first_too_slow(inner)
    return exc
