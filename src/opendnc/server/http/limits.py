"""Limits on what one HTTP client may hold: header and body deadlines, body size, connections.

uvicorn parses a request's headers before the app sees it and has no deadline for them, so
a client that sends a header byte every few seconds (slowloris) held its socket for as long
as it liked; two hundred of those starve a server with 1,024 file descriptors. Three guards,
all in this module (docs/server.md#limits):

* :func:`guarded_protocol` subclasses uvicorn's HTTP protocol: a connection must deliver a
  complete request line and headers within ``header_timeout`` seconds of opening (or of the
  end of its previous response); otherwise it is answered 408 and closed. A connection beyond
  ``max_connections`` is answered 503 with a one-line reason and closed at once.
* :class:`LimitsMiddleware` (ASGI) counts a request body while it streams, chunked or not:
  past the route's limit it is refused with 413 before the rest is read (a ``Content-Length``
  above it at once); a body that trickles (nothing for ``body_timeout`` seconds, or less than
  ``body_min_rate`` bytes a second on average after that) is refused with 408. Both close the
  connection.
* After a burst of connections ends, the C allocator is asked to give freed memory back
  (``malloc_trim``), so the server's memory returns near its baseline.
"""

from __future__ import annotations

import asyncio
import ctypes
import ctypes.util
import json
import logging
import time
from dataclasses import dataclass, field
from typing import Any

from starlette.exceptions import HTTPException
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from opendnc.server.library.versions import MAX_PROGRAM_BYTES

__all__ = [
    "BodyRefused",
    "Limits",
    "LimitsMiddleware",
    "default_max_connections",
    "guarded_protocol",
    "raise_file_limit",
    "trim_memory",
]

log = logging.getLogger("opendnc.server.http.limits")

# Descriptors kept back from connections: the database pool, the machines' links, the
# library's files, the log.
RESERVED_FILES = 256


def raise_file_limit() -> int:
    """Raise this process's soft limit of open files to its hard limit; the new soft limit.

    Windows has no such limit to raise (its sockets are not counted against one): 4096.
    """
    try:
        import resource
    except ImportError:
        return 4096 + RESERVED_FILES
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if hard == resource.RLIM_INFINITY:
        hard = max(soft, 65536)
    if soft != resource.RLIM_INFINITY and soft < hard:
        try:
            resource.setrlimit(resource.RLIMIT_NOFILE, (hard, hard))
            soft = hard
        except (ValueError, OSError):  # pragma: no cover - a platform that refuses
            pass
    return int(soft)


def default_max_connections() -> int:
    """Connections the server accepts at once: what the open-files limit leaves, at most 4096."""
    try:
        import resource  # POSIX only: see raise_file_limit
    except ImportError:
        return 4096
    soft, _hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft == resource.RLIM_INFINITY:
        return 4096
    return max(16, min(4096, int(soft) - RESERVED_FILES))


def _program_upload(method: str, path: str) -> bool:
    # The API's upload, the dashboard's library upload and its upload to a control's folder.
    return (
        (method == "PUT" and path.startswith("/api/programs/"))
        or (method == "POST" and path == "/library")
        or (method == "POST" and path.startswith("/machines/") and path.endswith("/files/upload"))
    )


@dataclass(frozen=True)
class Limits:
    """The server's limits (seconds, bytes, connections)."""

    header_timeout: float = 10.0
    body_timeout: float = 20.0
    body_min_rate: float = 1024.0
    max_body: int = 1 << 20  # JSON and forms
    max_upload: int = MAX_PROGRAM_BYTES  # a program's bytes
    max_connections: int = field(default_factory=default_max_connections)

    def body_limit(self, method: str, path: str) -> int:
        """The most bytes a request's body may have."""
        return self.max_upload if _program_upload(method, path) else self.max_body


class BodyRefused(HTTPException):
    """A request body that is too large or too slow (the connection is closed after it)."""

    def __init__(self, status_code: int, detail: str) -> None:
        super().__init__(status_code, detail, headers={"Connection": "close"})


def _too_large(limit: int) -> BodyRefused:
    return BodyRefused(413, f"the request body is larger than the {limit} bytes this takes")


class LimitsMiddleware:
    """Refuse request bodies above the route's limit or arriving too slowly (see module)."""

    def __init__(self, app: ASGIApp, limits: Limits | None = None) -> None:
        self.app = app
        self.limits = limits or Limits()

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        limits = self.limits
        limit = limits.body_limit(scope["method"], scope["path"])
        length = _content_length(scope)
        started = False

        async def send_tracked(message: Message) -> None:
            nonlocal started
            if message["type"] == "http.response.start":
                started = True
            await send(message)

        if length is not None and length > limit:
            await _refuse(_too_large(limit), send)
            return
        begun = time.monotonic()
        received = 0
        # A request without a body (no length, not chunked) has nothing to time: its receive
        # only waits for the client to leave (an event stream's disconnect check).
        done = not (length or _chunked(scope))

        async def limited_receive() -> Message:
            nonlocal received, done
            if done:
                return await receive()
            now = time.monotonic()
            # The body may take body_timeout seconds, plus a second per body_min_rate bytes
            # that already came: a large upload on a slow line goes on, a trickle does not.
            allowed = begun + limits.body_timeout + received / limits.body_min_rate
            wait = min(allowed - now, limits.body_timeout)
            try:
                message = await asyncio.wait_for(receive(), max(wait, 0.001))
            except TimeoutError:
                raise BodyRefused(
                    408, "the request body did not arrive in time; send it in one go"
                ) from None
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > limit:
                    raise _too_large(limit)
                done = not message.get("more_body", False)
            return message

        try:
            await self.app(scope, limited_receive, send_tracked)
        except BodyRefused as exc:
            # A route that let it through (a stream read outside the routing's handlers).
            if started:
                raise
            await _refuse(exc, send)
        finally:
            if received > limits.max_body:
                # A large body was read (and has been dropped by now): its memory goes back.
                asyncio.get_running_loop().call_soon(trim_memory)


def _chunked(scope: Scope) -> bool:
    return any(
        name == b"transfer-encoding" and b"chunked" in value.lower()
        for name, value in scope["headers"]
    )


def _content_length(scope: Scope) -> int | None:
    for name, value in scope["headers"]:
        if name == b"content-length":
            try:
                return int(value)
            except ValueError:
                return None
    return None


async def _refuse(exc: BodyRefused, send: Send) -> None:
    body = json.dumps({"detail": exc.detail}).encode()
    await send(
        {
            "type": "http.response.start",
            "status": exc.status_code,
            "headers": [
                (b"content-type", b"application/json"),
                (b"content-length", str(len(body)).encode()),
                (b"connection", b"close"),
            ],
        }
    )
    await send({"type": "http.response.body", "body": body})


# -- the connection's side -------------------------------------------------------------------


def _plain_response(status: int, reason: str, text: str) -> bytes:
    body = (text + "\n").encode()
    return (
        f"HTTP/1.1 {status} {reason}\r\ncontent-type: text/plain; charset=utf-8\r\n"
        f"content-length: {len(body)}\r\nconnection: close\r\n\r\n"
    ).encode() + body


_libc: Any = None


def trim_memory() -> None:
    """Give freed heap memory back to the system (glibc only; elsewhere nothing)."""
    global _libc
    if _libc is None:
        name = ctypes.util.find_library("c")
        try:
            _libc = ctypes.CDLL(name) if name else False
        except OSError:  # pragma: no cover
            _libc = False
        if _libc and not hasattr(_libc, "malloc_trim"):  # pragma: no cover - not glibc
            _libc = False
    if _libc:
        _libc.malloc_trim(0)


class _Trimmer:
    """Trims memory once the connections fall well below a peak they reached."""

    def __init__(self) -> None:
        self.peak = 0
        self.handle: asyncio.TimerHandle | None = None

    def opened(self, count: int) -> None:
        self.peak = max(self.peak, count)

    def closed(self, count: int, loop: asyncio.AbstractEventLoop) -> None:
        if self.peak >= 64 and count <= self.peak // 4 and self.handle is None:
            self.handle = loop.call_later(1.0, self._trim)

    def _trim(self) -> None:
        self.handle = None
        self.peak = 0
        trim_memory()


_trimmer = _Trimmer()


def guarded_protocol(base: type[Any], limits: Limits) -> type[Any]:
    """uvicorn's HTTP protocol class ``base`` with a header deadline and a connection limit."""

    class Guarded(base):  # type: ignore[misc]
        _header_timer: asyncio.TimerHandle | None = None
        _seen_cycle: Any = None

        def connection_made(self, transport: Any) -> None:
            super().connection_made(transport)
            count = len(self.connections)
            _trimmer.opened(count)
            if count > limits.max_connections:
                transport.write(
                    _plain_response(
                        503,
                        "Service Unavailable",
                        f"the server has {limits.max_connections} connections open, its "
                        "limit; try again shortly",
                    )
                )
                transport.close()
                return
            self._arm_header_timer()

        def connection_lost(self, exc: Exception | None) -> None:
            self._cancel_header_timer()
            super().connection_lost(exc)
            _trimmer.closed(len(self.connections), self.loop)

        def data_received(self, data: bytes) -> None:
            super().data_received(data)
            cycle = getattr(self, "cycle", None)
            if cycle is not None and cycle is not self._seen_cycle:
                self._seen_cycle = cycle  # a request's headers are complete
                self._cancel_header_timer()

        def on_response_complete(self) -> None:
            super().on_response_complete()
            if not self.transport.is_closing():
                self._arm_header_timer()  # the next request on this connection

        def _arm_header_timer(self) -> None:
            self._cancel_header_timer()
            self._header_timer = self.loop.call_later(limits.header_timeout, self._headers_late)

        def _cancel_header_timer(self) -> None:
            if self._header_timer is not None:
                self._header_timer.cancel()
                self._header_timer = None

        def _headers_late(self) -> None:
            self._header_timer = None
            if self.transport.is_closing():
                return
            cycle = getattr(self, "cycle", None)
            if cycle is not None and cycle is not self._seen_cycle:
                return  # pragma: no cover - headers completed in this very loop turn
            if cycle is None or cycle.response_complete:
                self.transport.write(
                    _plain_response(
                        408,
                        "Request Timeout",
                        f"the request's headers did not arrive within {limits.header_timeout:g} s",
                    )
                )
            self.transport.close()

    Guarded.__name__ = f"Guarded{base.__name__}"
    Guarded.__qualname__ = Guarded.__name__
    return Guarded


def uvicorn_protocol(limits: Limits) -> type[Any]:
    """The guarded HTTP protocol for uvicorn's ``http=`` setting (httptools if installed)."""
    try:
        from uvicorn.protocols.http.httptools_impl import HttpToolsProtocol

        return guarded_protocol(HttpToolsProtocol, limits)
    except ImportError:  # pragma: no cover - httptools is part of uvicorn[standard]
        from uvicorn.protocols.http.h11_impl import H11Protocol

        return guarded_protocol(H11Protocol, limits)
