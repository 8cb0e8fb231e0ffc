"""Drivers that run LSV2 operations (generators of :mod:`opendnc.lsv2.ops`) over real I/O.

:class:`BlockingDriver` runs them over a blocking :class:`~opendnc.transport.ByteStream`,
:class:`AsyncDriver` over asyncio streams. Both own one :class:`Lsv2Connection` engine and a
:class:`SessionState` and run the same pump (``_DriverBase._pump``), which turns an operation's
steps into writes and timed reads; a driver only performs those, blocking or with ``await``,
and holds no protocol logic of its own. Timeouts and socket errors come out as the opendnc
error tree.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Generator
from typing import TypeVar

from opendnc.errors import (
    PeerClosed,
    RemoteProtocolError,
    TransportError,
    TransportTimeout,
    os_reason,
)
from opendnc.lsv2.connection import BytesHook, Lsv2Connection, Role, State, TraceHook
from opendnc.lsv2.messages import Message
from opendnc.lsv2.ops.base import Expect, Op, Receive, Send, SessionState, Slow
from opendnc.lsv2.serial_stream import AsyncSerialLink, SerialLine, open_lsv2_serial
from opendnc.transport.base import ByteStream
from opendnc.transport.tcp import TcpStream

__all__ = ["AsyncDriver", "BlockingDriver"]

T = TypeVar("T")
READ_SIZE = 65536

_Pump = Generator[bytes | float, bytes, T]
"""What a driver runs: yields bytes to write or a read timeout, returns the op's result."""


class _DriverBase:
    def __init__(
        self,
        timeout: float,
        safe_mode: bool,
        trace: TraceHook | None,
        trace_bytes: BytesHook | None = None,
    ) -> None:
        self.timeout = timeout
        self.conn = Lsv2Connection(Role.CLIENT, on_message=trace, on_bytes=trace_bytes)
        self.state = SessionState(safe_mode=safe_mode)
        self.broken = False
        """Set after a transport or protocol error: the link is out of step, reconnect."""

    def check_usable(self) -> None:
        """Refuse to run on a link that failed earlier."""
        if self.broken:
            raise TransportError("the LSV2 connection failed earlier; reconnect")

    def _after(self, op: Op[T]) -> None:
        op.close()
        # Interrupted while an answer was due (timeout, cancellation, Ctrl-C): that answer may
        # still arrive and would be taken for the next one, so this link is out of step.
        if self.conn.state is State.WAITING:
            self.broken = True

    def _pump(self, op: Op[T]) -> _Pump[T]:
        """Run ``op`` against the engine; yield what the driver must do, return the result.

        The one place that turns steps into I/O for both drivers: it yields ``bytes`` to write
        (and is sent anything back) or a read timeout in seconds (and is sent the bytes read;
        the driver raises :class:`TransportTimeout` / :class:`PeerClosed` itself).
        """
        conn, send_op, timeout = self.conn, op.send, self.timeout
        try:
            step = next(op)
            while True:
                # exact types, most frequent first: this runs for every file block
                if type(step) is Send:
                    yield conn.send(step.message)
                    # the operation works while the answer travels, then sends Receive
                    step = send_op(None)
                    continue
                if type(step) is Receive:
                    wait = timeout
                elif type(step) is Slow:
                    yield conn.send(step.message)
                    wait = max(step.timeout, timeout)
                elif type(step) is Expect:
                    step = send_op((yield from self._notice(step.timeout)))
                    continue
                else:
                    assert isinstance(step, Message)
                    yield conn.send(step)
                    wait = timeout
                if conn.state is not State.WAITING:
                    reply = None  # e.g. T_FD without secure send: the control stays silent
                else:
                    while (reply := conn.next_event()) is None:
                        conn.receive_data((yield wait))
                step = send_op(reply)
        except StopIteration as done:
            result: T = done.value
            return result

    def _notice(self, timeout: float) -> Generator[float, bytes, Message]:
        conn = self.conn
        deadline = time.monotonic() + timeout
        while (notice := conn.next_notice()) is None:
            left = deadline - time.monotonic()
            if left <= 0:
                raise TransportTimeout(f"no M_CC completion message within {timeout:g} s")
            conn.receive_data((yield left))
            conn.next_event()
        return notice


class BlockingDriver(_DriverBase):
    """Runs operations over a blocking byte stream."""

    def __init__(
        self,
        stream: ByteStream,
        *,
        timeout: float = 10.0,
        safe_mode: bool = True,
        trace: TraceHook | None = None,
        trace_bytes: BytesHook | None = None,
    ) -> None:
        super().__init__(timeout, safe_mode, trace, trace_bytes)
        self.stream = stream
        self._read_timeout: float | None = None

    @classmethod
    def open(
        cls,
        host: str,
        port: int,
        *,
        timeout: float = 10.0,
        safe_mode: bool = True,
        trace: TraceHook | None = None,
        trace_bytes: BytesHook | None = None,
        serial: SerialLine | None = None,
    ) -> BlockingDriver:
        """Connect by TCP (``TcpStream`` sets ``TCP_NODELAY``), or over RS-232 with ``serial``
        (``trace_bytes`` then sees the serial line's own bytes)."""
        if serial is not None:
            line = open_lsv2_serial(serial, on_link=trace_bytes)
            driver = cls(line, timeout=timeout, safe_mode=safe_mode, trace=trace)
            driver.state.sizer = line.sizer  # upload blocks follow the line
            return driver
        stream = TcpStream(host, port, timeout=timeout)
        return cls(
            stream, timeout=timeout, safe_mode=safe_mode, trace=trace, trace_bytes=trace_bytes
        )

    def run(self, op: Op[T]) -> T:
        """Run ``op`` to completion and return its result."""
        self.check_usable()
        pump = self._pump(op)
        stream = self.stream
        try:
            request = next(pump)
            while True:
                if isinstance(request, bytes):
                    stream.write(request)
                    request = pump.send(b"")
                else:
                    if request != self._read_timeout:
                        stream.set_timeout(request)
                        self._read_timeout = request
                    request = pump.send(stream.read(READ_SIZE))
        except StopIteration as done:
            result: T = done.value
            return result
        except (TransportError, RemoteProtocolError):
            self.broken = True
            raise
        finally:
            pump.close()
            self._after(op)

    def close(self) -> None:
        """Close the stream."""
        self.stream.close()


class _LinkProtocol(asyncio.Protocol):
    """Minimal asyncio protocol: collects received chunks and wakes one waiting reader.

    Lighter than ``StreamReader``/``StreamWriter`` (no extra buffer copy, one future and one
    timer per wait), which matters at thousands of telegrams per second.
    """

    def __init__(self) -> None:
        self.transport: asyncio.Transport | None = None
        self._chunks: list[bytes] = []
        self._waiter: asyncio.Future[None] | None = None
        self._drained: asyncio.Future[None] | None = None
        self._gone: str | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        self.transport = transport

    def data_received(self, data: bytes) -> None:
        self._chunks.append(data)
        self._wake()

    def eof_received(self) -> bool:
        self._gone = "the control closed the connection"
        self._wake()
        return False

    def connection_lost(self, exc: Exception | None) -> None:
        self._gone = f"connection lost: {exc}" if exc else "the control closed the connection"
        self._wake()
        self.resume_writing()

    def pause_writing(self) -> None:
        if self._drained is None:
            self._drained = asyncio.get_running_loop().create_future()

    def resume_writing(self) -> None:
        drained, self._drained = self._drained, None
        if drained is not None and not drained.done():
            drained.set_result(None)

    def _wake(self) -> None:
        waiter = self._waiter
        if waiter is not None and not waiter.done():
            waiter.set_result(None)

    async def write(self, data: bytes) -> None:
        """Send ``data``; waits only if the transport asked us to pause."""
        transport = self.transport
        if transport is None or transport.is_closing() or self._gone:
            raise PeerClosed(self._gone or "the connection is closed")
        transport.write(data)
        if self._drained is not None:
            await self._drained

    async def read(self, timeout: float) -> bytes:
        """Return received bytes, waiting up to ``timeout`` seconds for some."""
        if not self._chunks:
            if self._gone:
                raise PeerClosed(self._gone)
            loop = asyncio.get_running_loop()
            waiter: asyncio.Future[None] = loop.create_future()
            self._waiter = waiter
            timer = loop.call_later(timeout, _expire, waiter)
            try:
                await waiter
            finally:
                timer.cancel()
                self._waiter = None
            if not self._chunks:
                if self._gone:
                    raise PeerClosed(self._gone)
                raise TransportTimeout(f"no answer within {timeout:g} s")
        chunks = self._chunks
        data = chunks[0] if len(chunks) == 1 else b"".join(chunks)
        chunks.clear()
        return data


def _expire(waiter: asyncio.Future[None]) -> None:
    if not waiter.done():
        waiter.set_result(None)


class AsyncDriver(_DriverBase):
    """Runs operations over an asyncio TCP connection."""

    def __init__(
        self,
        link: _LinkProtocol | AsyncSerialLink,
        *,
        timeout: float = 10.0,
        safe_mode: bool = True,
        trace: TraceHook | None = None,
        trace_bytes: BytesHook | None = None,
    ) -> None:
        super().__init__(timeout, safe_mode, trace, trace_bytes)
        self._link = link
        self._lock = asyncio.Lock()

    @classmethod
    async def open(
        cls,
        host: str,
        port: int,
        *,
        timeout: float = 10.0,
        safe_mode: bool = True,
        trace: TraceHook | None = None,
        trace_bytes: BytesHook | None = None,
        serial: SerialLine | None = None,
    ) -> AsyncDriver:
        """Connect by TCP (asyncio sets ``TCP_NODELAY`` on TCP transports), or over RS-232
        with ``serial`` (``trace_bytes`` then sees the serial line's own bytes)."""
        if serial is not None:
            link = await AsyncSerialLink.open(serial, on_link=trace_bytes)
            adriver = cls(link, timeout=timeout, safe_mode=safe_mode, trace=trace)
            adriver.state.sizer = link.stream.sizer  # upload blocks follow the line
            return adriver
        loop = asyncio.get_running_loop()
        try:
            async with asyncio.timeout(timeout):
                _, tcp = await loop.create_connection(_LinkProtocol, host, port)
        except TimeoutError as exc:
            raise TransportTimeout(f"connecting to {host}:{port} timed out") from exc
        except OSError as exc:
            raise TransportError(f"cannot connect to {host}:{port}: {os_reason(exc)}") from exc
        return cls(tcp, timeout=timeout, safe_mode=safe_mode, trace=trace, trace_bytes=trace_bytes)

    async def run(self, op: Op[T]) -> T:
        """Run ``op`` to completion; concurrent calls are serialised (half-duplex link)."""
        async with self._lock:
            self.check_usable()
            pump = self._pump(op)
            link = self._link
            try:
                request = next(pump)
                while True:
                    if isinstance(request, bytes):
                        await link.write(request)
                        request = pump.send(b"")
                    else:
                        request = pump.send(await link.read(request))
            except StopIteration as done:
                result: T = done.value
                return result
            except (TransportError, RemoteProtocolError):
                self.broken = True
                raise
            finally:
                pump.close()
                self._after(op)

    async def close(self) -> None:
        """Close the connection."""
        if isinstance(self._link, AsyncSerialLink):
            await self._link.close()
        elif self._link.transport is not None:
            self._link.transport.close()
