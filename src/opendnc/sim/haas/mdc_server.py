"""MDC over TCP for the virtual Haas (NGC Setting 143 = port).

As Haas documents: at most two simultaneous connections (a third is closed at once), and
every reply goes to every open connection. Requests are parsed with the shared codec in
:mod:`opendnc.haas.mdc`; the answer comes from :meth:`HaasControl.handle_mdc`.

Broadcasting never waits on a connection: each reply is handed to every connection's
transport at once. A connection that stops reading is watched instead: once its unread
replies pass the transport's high-water mark it has ``drain_timeout`` seconds to take them,
and holding more than ``max_buffered`` bytes drops it at once; either way it is closed and its
slot freed (:attr:`MdcServer.dropped` counts them). The other client is never held up by it.

Each connection's kernel send buffer is kept small (:data:`SEND_BUFFER`): left to itself,
Linux grows a loopback socket's buffer to megabytes, which hides a reader that stopped for as
long as it takes to fill them (tens of seconds under load), where a control's network stack
would have pushed back after a few kilobytes.
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
from collections.abc import Callable

from opendnc.errors import RemoteProtocolError
from opendnc.haas import mdc
from opendnc.sim.haas.control import HaasControl

SESSION_END_TIMEOUT = 2.0  # seconds close() waits for its connection handlers to end

MAX_CONNECTIONS = 2
DRAIN_TIMEOUT = 5.0
"""Seconds a connection may leave replies unread (past the high-water mark) before it is dropped."""
SEND_BUFFER = 64 * 1024
"""Kernel send buffer per connection (SO_SNDBUF), so the watch above sees a stopped reader."""
MAX_BUFFERED = 1 << 20
"""Bytes of unread replies kept for one connection; past this it is dropped at once."""


class MdcResponder:
    """Sans-IO MDC answering for one link: request bytes in, framed reply bytes out.

    The TCP server runs one per connection; a serial front-end (classic Setting 143) can run
    one on its port the same way: ``port.write(b"".join(responder.feed(data)))``.
    """

    def __init__(self, control: HaasControl) -> None:
        self.control = control
        self._framer = mdc.LineFramer()
        self._ignore_next = control.config.ignore_first_query

    def feed(self, data: bytes) -> list[bytes]:
        """Framed replies to every complete request in ``data`` (garbage gets "unknown")."""
        replies: list[bytes] = []
        try:
            self._framer.feed(data)
        except RemoteProtocolError:
            replies.append(self._reply(mdc.UnknownRequest("")))
        while (line := self._framer.next_line()) is not None:
            if self._ignore_next:
                self._ignore_next = False
                continue
            replies.append(self._reply(mdc.parse_request(line)))
        return replies

    def _reply(self, request: mdc.Request | mdc.UnknownRequest) -> bytes:
        reply = self.control.handle_mdc(request)
        return mdc.frame_reply(reply.to_payload(), self.control.control_type)


Trace = Callable[[str, bytes], None]
"""``trace(direction, data)``: direction is ``"rx"`` or ``"tx"``."""


class MdcServer:
    """Serve :class:`HaasControl` MDC on a TCP port; port 0 picks a free one."""

    def __init__(
        self,
        control: HaasControl,
        host: str = "127.0.0.1",
        port: int = 0,
        *,
        trace: Trace | None = None,
        max_connections: int = MAX_CONNECTIONS,
        drain_timeout: float = DRAIN_TIMEOUT,
        max_buffered: int = MAX_BUFFERED,
    ) -> None:
        self.control = control
        self.host, self.port = host, port
        self.trace = trace
        self.max_connections = max_connections
        self.drain_timeout = drain_timeout
        self.max_buffered = max_buffered
        self.writers: list[asyncio.StreamWriter] = []
        self.refused = 0
        self.dropped = 0
        """Connections dropped because they stopped reading their replies."""
        self._server: asyncio.Server | None = None
        # the connection handlers still running: close() lets them end before it returns, or
        # a stop would cancel them mid-read and Python 3.11 logs that as a traceback
        self._sessions: set[asyncio.Task[None]] = set()
        self._watchdogs: dict[asyncio.StreamWriter, asyncio.Task[None]] = {}

    async def start(self) -> int:
        """Start listening; returns the bound port."""
        self._server = await asyncio.start_server(self._session, self.host, self.port)
        self.port = self._server.sockets[0].getsockname()[1]
        return self.port

    async def close(self) -> None:
        """Stop listening and drop every connection."""
        if self._server is not None:
            self._server.close()
        for task in list(self._watchdogs.values()):
            task.cancel()
        for writer in list(self.writers):
            writer.transport.abort()  # unread replies need not be flushed
        if self._sessions:
            await asyncio.wait(list(self._sessions), timeout=SESSION_END_TIMEOUT)
        if self._server is not None:
            with contextlib.suppress(OSError):
                await self._server.wait_closed()

    async def _session(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        if task is not None:
            self._sessions.add(task)
            task.add_done_callback(self._sessions.discard)
        if len(self.writers) >= self.max_connections:
            self.refused += 1
            writer.close()
            return
        sock = writer.get_extra_info("socket")
        if sock is not None:
            with contextlib.suppress(OSError):
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, SEND_BUFFER)
        self.writers.append(writer)
        responder = MdcResponder(self.control)
        try:
            while data := await reader.read(4096):
                if self.trace:
                    self.trace("rx", data)
                for reply in responder.feed(data):
                    self._broadcast(reply)
        except OSError:
            pass  # the client vanished; just forget it
        finally:
            if writer in self.writers:
                self.writers.remove(writer)
            writer.close()

    def _broadcast(self, data: bytes) -> None:
        if self.trace:
            self.trace("tx", data)
        for writer in list(self.writers):
            self._send(writer, data)

    def _send(self, writer: asyncio.StreamWriter, data: bytes) -> None:
        if writer.is_closing():
            self._forget(writer)
            return
        writer.write(data)
        buffered = writer.transport.get_write_buffer_size()
        if buffered > self.max_buffered:
            self._drop(writer)
        elif buffered and writer not in self._watchdogs:
            self._watchdogs[writer] = asyncio.create_task(self._watch(writer))

    async def _watch(self, writer: asyncio.StreamWriter) -> None:
        # drain() returns at once below the high-water mark and otherwise waits until the
        # peer has read enough: a bounded wait tells a slow reader from one that stopped.
        try:
            await asyncio.wait_for(writer.drain(), self.drain_timeout)
        except TimeoutError:
            self._drop(writer)
        except OSError:
            self._forget(writer)
        finally:
            self._watchdogs.pop(writer, None)

    def _drop(self, writer: asyncio.StreamWriter) -> None:
        if writer in self.writers:
            self.dropped += 1
        self._forget(writer)
        writer.transport.abort()  # close() would wait to flush what it will never read

    def _forget(self, writer: asyncio.StreamWriter) -> None:
        if writer in self.writers:
            self.writers.remove(writer)
