"""Drivers that run LSV2 operations (generators of :mod:`opendnc.lsv2.ops`) over real I/O.

:class:`BlockingDriver` runs them over a blocking :class:`~opendnc.transport.ByteStream`,
:class:`AsyncDriver` over asyncio streams. Both own one :class:`Lsv2Connection` engine and a
:class:`SessionState`, translate timeouts and socket errors into the opendnc error tree, and
hold no protocol logic of their own.
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from typing import TypeVar

from opendnc.errors import PeerClosed, RemoteProtocolError, TransportError, TransportTimeout
from opendnc.lsv2.connection import BytesHook, Lsv2Connection, Role, State, TraceHook
from opendnc.lsv2.messages import Message
from opendnc.lsv2.ops.base import Expect, Op, SessionState, Slow, Step
from opendnc.transport.base import ByteStream
from opendnc.transport.tcp import TcpStream

__all__ = ["AsyncDriver", "BlockingDriver"]

T = TypeVar("T")
READ_SIZE = 65536


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

    def _unpack(self, step: Step) -> tuple[Message | None, float]:
        if isinstance(step, Slow):
            return step.message, max(step.timeout, self.timeout)
        if isinstance(step, Expect):
            return None, step.timeout
        return step, self.timeout


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
    ) -> BlockingDriver:
        """Connect by TCP (``TcpStream`` sets ``TCP_NODELAY``)."""
        stream = TcpStream(host, port, timeout=timeout)
        return cls(
            stream, timeout=timeout, safe_mode=safe_mode, trace=trace, trace_bytes=trace_bytes
        )

    def run(self, op: Op[T]) -> T:
        """Run ``op`` to completion and return its result."""
        self.check_usable()
        try:
            step = next(op)
            while True:
                step = op.send(self._exchange(step))
        except StopIteration as done:
            result: T = done.value
            return result
        except (TransportError, RemoteProtocolError):
            self.broken = True
            raise
        finally:
            self._after(op)

    def _exchange(self, step: Step) -> Message | None:
        message, timeout = self._unpack(step)
        conn = self.conn
        if message is None:
            return self._wait_notice(timeout)
        self.stream.write(conn.send(message))
        if not conn.expects_reply(message):
            return None
        if timeout != self._read_timeout:
            self.stream.set_timeout(timeout)
            self._read_timeout = timeout
        while (reply := conn.next_event()) is None:
            conn.receive_data(self.stream.read(READ_SIZE))
        return reply

    def _wait_notice(self, timeout: float) -> Message:
        deadline = time.monotonic() + timeout
        while (notice := self.conn.next_notice()) is None:
            left = deadline - time.monotonic()
            if left <= 0:
                raise TransportTimeout(f"no M_CC completion message within {timeout:g} s")
            self.stream.set_timeout(left)
            self._read_timeout = left
            self.conn.receive_data(self.stream.read(READ_SIZE))
            self.conn.next_event()
        return notice

    def close(self) -> None:
        """Close the stream."""
        self.stream.close()


class AsyncDriver(_DriverBase):
    """Runs operations over asyncio streams."""

    def __init__(
        self,
        reader: asyncio.StreamReader,
        writer: asyncio.StreamWriter,
        *,
        timeout: float = 10.0,
        safe_mode: bool = True,
        trace: TraceHook | None = None,
        trace_bytes: BytesHook | None = None,
    ) -> None:
        super().__init__(timeout, safe_mode, trace, trace_bytes)
        self.reader, self.writer = reader, writer
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
    ) -> AsyncDriver:
        """Connect by TCP (asyncio sets ``TCP_NODELAY`` on TCP transports)."""
        try:
            async with asyncio.timeout(timeout):
                reader, writer = await asyncio.open_connection(host, port)
        except TimeoutError as exc:
            raise TransportTimeout(f"connecting to {host}:{port} timed out") from exc
        except OSError as exc:
            raise TransportError(f"cannot connect to {host}:{port}: {exc}") from exc
        return cls(
            reader,
            writer,
            timeout=timeout,
            safe_mode=safe_mode,
            trace=trace,
            trace_bytes=trace_bytes,
        )

    async def run(self, op: Op[T]) -> T:
        """Run ``op`` to completion; concurrent calls are serialised (half-duplex link)."""
        async with self._lock:
            self.check_usable()
            try:
                step = next(op)
                while True:
                    step = op.send(await self._exchange(step))
            except StopIteration as done:
                result: T = done.value
                return result
            except (TransportError, RemoteProtocolError):
                self.broken = True
                raise
            finally:
                self._after(op)

    async def _read(self, timeout: float) -> bytes:
        try:
            async with asyncio.timeout(timeout):
                data = await self.reader.read(READ_SIZE)
        except TimeoutError as exc:
            raise TransportTimeout(f"no answer within {timeout:g} s") from exc
        except OSError as exc:
            raise TransportError(f"receive failed: {exc}") from exc
        if not data:
            raise PeerClosed("the control closed the connection")
        return data

    async def _exchange(self, step: Step) -> Message | None:
        message, timeout = self._unpack(step)
        conn = self.conn
        if message is None:
            return await self._wait_notice(timeout)
        try:
            self.writer.write(conn.send(message))
            await self.writer.drain()
        except OSError as exc:
            raise TransportError(f"send failed: {exc}") from exc
        if not conn.expects_reply(message):
            return None
        while (reply := conn.next_event()) is None:
            conn.receive_data(await self._read(timeout))
        return reply

    async def _wait_notice(self, timeout: float) -> Message:
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout
        while (notice := self.conn.next_notice()) is None:
            left = deadline - loop.time()
            if left <= 0:
                raise TransportTimeout(f"no M_CC completion message within {timeout:g} s")
            self.conn.receive_data(await self._read(left))
            self.conn.next_event()
        return notice

    async def close(self) -> None:
        """Close the connection."""
        self.writer.close()
        # The peer may already have reset the connection; closing is all we wanted.
        with contextlib.suppress(OSError):
            await self.writer.wait_closed()
