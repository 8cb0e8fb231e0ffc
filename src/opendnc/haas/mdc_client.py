"""MDC clients: blocking (:class:`MdcClient`) and asyncio (:class:`AsyncMdcClient`).

Two layers, both written once and shared by the two clients:

* every procedure is a generator op: it yields requests and is sent the matching replies;
* :class:`MdcClientCore` runs an op over the :class:`~opendnc.haas.mdc.MdcConnection` codec
  and decides everything about the conversation: taking in other clients' broadcast replies
  before a request, the deadline for each reply, re-sending the first query of a connection
  (a Haas may leave it unanswered), and the typed error when the control stops reading or
  answering. It does no I/O: it yields :class:`Send` and :class:`Receive` steps.

The two clients are thin drivers that carry out those steps with a socket or with asyncio
streams and map OS errors onto the opendnc tree; they hold no protocol logic, so they cannot
drift apart.
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import Callable, Generator
from dataclasses import dataclass
from typing import TypeVar

from opendnc.errors import (
    ControlRefused,
    PeerClosed,
    RemoteProtocolError,
    SafetyLockError,
    TransportError,
    TransportTimeout,
    os_reason,
)
from opendnc.haas import macros
from opendnc.haas.mdc import (
    QUERIES,
    Busy,
    Count,
    Duration,
    MacroRead,
    MacroValue,
    MacroWrite,
    MdcConnection,
    Mode,
    ProgramStatus,
    Query,
    Refused,
    Reply,
    Request,
    TextValue,
    WriteAccepted,
    encode_request,
)
from opendnc.transport.base import ByteStream
from opendnc.transport.tcp import TcpStream

T = TypeVar("T")
Op = Generator[Request, Reply, T]

DEFAULT_PORT = 5051
DEFAULT_TIMEOUT = 3.0
"""Seconds a request may wait for its reply (and for the control to take the request)."""


# --------------------------------------------------------------------------- ops (no I/O)


def query_op(code: int, arg: int | None = None) -> Op[Reply]:
    """Ask ``?Q<code>`` (Q600 needs ``arg``, the variable number); return the typed reply."""
    request: Request = MacroRead(arg) if code == 600 and arg is not None else Query(code)
    reply = yield request
    return reply


def macro_get_op(var: int) -> Op[float]:
    """Read macro variable ``var`` with ``?Q600``."""
    reply = yield MacroRead(var)
    if isinstance(reply, Refused):
        raise ControlRefused(0, reply.text, context=f"Q600 {var}")
    if not isinstance(reply, MacroValue):
        raise RemoteProtocolError(f"expected a MACRO reply to Q600 {var}, got {reply!r}")
    return reply.value


def macro_set_op(var: int, value: float) -> Op[None]:
    """Write macro variable ``var`` with ``?E``; :class:`ControlRefused` on ``?``."""
    reply = yield MacroWrite(var, value)
    if isinstance(reply, Refused):
        raise ControlRefused(0, reply.text, context=f"E{var}")
    if not isinstance(reply, WriteAccepted):
        raise RemoteProtocolError(f"expected ! after E{var}, got {reply!r}")


@dataclass(frozen=True, slots=True)
class MachineStatus:
    """One readable summary built from several Q commands (``None`` = not answered)."""

    serial: str | None
    software: str | None
    model: str | None
    mode: str | None
    program: str | None
    status: str
    parts: int | None
    tool: int | None
    tool_changes: int | None
    power_on_seconds: int | None
    cutting_seconds: int | None
    last_cycle_seconds: int | None
    previous_cycle_seconds: int | None
    m30_counter_1: int | None
    m30_counter_2: int | None


def status_op() -> Op[MachineStatus]:
    """Collect a :class:`MachineStatus` (refused queries leave their field ``None``)."""
    values: dict[int, Reply] = {}
    for code in QUERIES:
        values[code] = yield Query(code)

    def text(code: int) -> str | None:
        reply = values[code]
        return reply.value if isinstance(reply, TextValue) else None

    def count(code: int) -> int | None:
        reply = values[code]
        return reply.value if isinstance(reply, Count) else None

    def seconds(code: int) -> int | None:
        reply = values[code]
        return reply.seconds if isinstance(reply, Duration) else None

    mode = values[104]
    q500 = values[500]
    program, status, parts = None, "UNKNOWN", None
    if isinstance(q500, ProgramStatus):
        program, status, parts = q500.program, q500.status, q500.parts
    elif isinstance(q500, Busy):
        status = "BUSY"
    return MachineStatus(
        serial=text(100),
        software=text(101),
        model=text(102),
        mode=mode.mode if isinstance(mode, Mode) else None,
        program=program,
        status=status,
        parts=parts,
        tool=count(201),
        tool_changes=count(200),
        power_on_seconds=seconds(300),
        cutting_seconds=seconds(301),
        last_cycle_seconds=seconds(303),
        previous_cycle_seconds=seconds(304),
        m30_counter_1=count(402),
        m30_counter_2=count(403),
    )


WRITABLE: tuple[range, ...] = (
    range(100, 200),  # legacy common globals
    range(500, 1000),  # legacy permanent globals
    range(10000, 10150),  # NGC globals (#100-#149 on legacy)
    range(10200, 10550),  # NGC-only and #500-#549 globals
    range(10600, 11000),  # NGC #600-#999 equivalents and new globals
)
"""Variables E writes may touch by default: general-purpose globals, not probe calibration
(#10150-#10199, #10550-#10599) nor any system variable (offsets, timers, counters)."""


def is_writable(var: int) -> bool:
    """True when ``var`` is on the default E-write allow-list (:data:`WRITABLE`)."""
    return any(var in span for span in WRITABLE)


def check_macro_write(
    var: int, value: float, *, safe_mode: bool = True, allow_any_variable: bool = False
) -> None:
    """Refuse locally, before anything is sent, a write that would not be carried out.

    First what the control itself refuses (:func:`opendnc.haas.macros.check_write`: no such
    variable, read-only, out of range, a fraction in a counter, the ``#3000`` alarm) as
    :class:`~opendnc.errors.InputError` with the reason, whatever the opt-ins; then the
    project's locks as :class:`SafetyLockError` (``safe_mode``, the :data:`WRITABLE` list).
    """
    macros.check_write(var, value)
    if safe_mode:
        raise SafetyLockError(f"writing macro variable #{var} over MDC")
    if not allow_any_variable and not is_writable(var):
        raise SafetyLockError(f"writing #{var} (not a general-purpose global; allow it explicitly)")


# --------------------------------------------------------------------------- sans-IO core


@dataclass(frozen=True, slots=True)
class Send:
    """I/O step: write ``data``, waiting at most ``timeout`` seconds for the peer to take it.

    The driver answers ``b""`` once it is written, ``None`` when the time ran out.
    """

    data: bytes
    timeout: float


@dataclass(frozen=True, slots=True)
class Receive:
    """I/O step: read up to 4096 bytes, waiting at most ``timeout`` seconds.

    The driver answers the bytes, ``b""`` when the peer closed, ``None`` when nothing came.
    """

    timeout: float


IoStep = Send | Receive
Io = Generator[IoStep, bytes | None, T]

WAITING = 0.0
"""Receive timeout that means "only what has already arrived"."""
ASYNC_WAITING = 0.001
"""What :data:`WAITING` becomes on asyncio, which only sees arrived bytes after a loop turn
(``wait_for`` with no time at all gives up before the read has run)."""
WAITING_BUDGET = 64 * 1024
"""Most bytes of other clients' replies taken in before a request (a flooding peer cannot
hold a request back for ever; what is left is skipped while the reply is awaited)."""


def _shown(request: Request) -> str:
    """``request`` as it goes on the wire, for messages (``?Q100``, ``?E100 2.5``)."""
    return encode_request(request, b"").decode("ascii")


class MdcClientCore:
    """The whole client-side conversation, without I/O (see the module docstring).

    ``timeout`` bounds each request: the control must take it and answer within that time,
    however many other clients' replies arrive meanwhile. ``clock`` is injectable for tests.
    """

    def __init__(
        self,
        *,
        timeout: float = DEFAULT_TIMEOUT,
        eol: bytes = b"\r\n",
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.conn = MdcConnection(eol)
        self.timeout = timeout
        self._clock = clock
        self._first = True

    def run(self, op: Op[T]) -> Io[T]:
        """Carry out ``op``: yields I/O steps, returns the op's result."""
        try:
            request = next(op)
            while True:
                reply = yield from self.exchange(request)
                request = op.send(reply)
        except StopIteration as done:
            result: T = done.value
            return result

    def exchange(self, request: Request) -> Io[Reply]:
        """Send ``request`` and return its reply.

        Haas notes that the first query after connecting may go unanswered, so the first
        request of a connection is sent a second time when its reply does not come.
        """
        attempts = 2 if self._first else 1
        self._first = False
        for _ in range(attempts):
            yield from self._take_waiting()
            if (yield Send(self.conn.send(request), self.timeout)) is None:
                self.conn.reset()
                raise TransportTimeout(
                    f"the control did not take {_shown(request)} within {self.timeout:g} s "
                    "(it stopped reading)"
                )
            reply = yield from self._await_reply(self._clock() + self.timeout)
            if reply is not None:
                return reply
            self.conn.reset()
        asked = " (asked twice)" if attempts == 2 else ""
        raise TransportTimeout(
            f"no MDC reply to {_shown(request)} within {self.timeout:g} s{asked}"
        )

    def _take_waiting(self) -> Io[None]:
        # Replies to other clients that are already here must not be taken for the answer to
        # the next request (replies are broadcast); take them in first, within a budget.
        taken = 0
        while taken < WAITING_BUDGET:
            data = yield Receive(WAITING)
            if not data:
                return  # nothing waiting (a closed peer shows up on the send or the reply)
            self.conn.receive_data(data)
            taken += len(data)

    def _await_reply(self, deadline: float) -> Io[Reply | None]:
        while (reply := self.conn.next_event()) is None:
            remaining = deadline - self._clock()
            if remaining <= 0:
                return None
            data = yield Receive(remaining)
            if data is None:
                return None
            self.conn.receive_data(data)  # b"": closed, next_event raises PeerClosed
        return reply


# --------------------------------------------------------------------------- blocking


class MdcClient:
    """Blocking MDC client over TCP (NGC, Setting 143 = port) or any byte stream.

    ``MdcClient(host, port)`` connects over TCP; :meth:`over` runs the same client on a
    stream that is already open and :meth:`open_serial` on a serial line (a classic control
    with Setting 143 ON answers on its RS-232 port, framing replies STX ... ETB CR LF ``>``;
    docs/haas.md#mdc). ``safe_mode`` (default on) refuses :meth:`macro_set` with
    :class:`SafetyLockError`; with it off, writes are still limited to :data:`WRITABLE` unless
    ``allow_any_variable``. A control that stops answering or reading gives
    :class:`TransportTimeout` (a reply waits at most ``timeout``; the socket itself lets a
    write wait up to ``max(timeout, 10 s)``).
    """

    def __init__(
        self,
        host: str,
        port: int = DEFAULT_PORT,
        *,
        timeout: float = DEFAULT_TIMEOUT,
        safe_mode: bool = True,
        allow_any_variable: bool = False,
        eol: bytes = b"\r\n",
        stream: ByteStream | None = None,
    ) -> None:
        self.safe_mode = safe_mode
        self.allow_any_variable = allow_any_variable
        self.core = MdcClientCore(timeout=timeout, eol=eol)
        self._stream: ByteStream = (
            stream if stream is not None else TcpStream(host, port, timeout=timeout)
        )

    @classmethod
    def over(
        cls,
        stream: ByteStream,
        *,
        timeout: float = DEFAULT_TIMEOUT,
        safe_mode: bool = True,
        allow_any_variable: bool = False,
        eol: bytes = b"\r\n",
    ) -> MdcClient:
        """A client on an open ``stream`` (a serial line the caller may share with XModem).

        :meth:`close` closes the stream; a caller that keeps the stream just drops the client.
        """
        return cls(
            "",
            timeout=timeout,
            safe_mode=safe_mode,
            allow_any_variable=allow_any_variable,
            eol=eol,
            stream=stream,
        )

    @classmethod
    def open_serial(
        cls,
        url: str,
        baud: int = 9600,
        *,
        parity: str = "N",
        bytesize: int = 8,
        stopbits: float = 1,
        timeout: float = DEFAULT_TIMEOUT,
        safe_mode: bool = True,
        allow_any_variable: bool = False,
        eol: bytes = b"\r\n",
    ) -> MdcClient:
        """A client on a serial line: a device, a pyserial URL or ``socket://HOST:PORT``."""
        from opendnc.transport.serial import open_stream  # pyserial only when used

        stream = open_stream(
            url, baud, timeout=timeout, parity=parity, bytesize=bytesize, stopbits=stopbits
        )
        return cls.over(
            stream,
            timeout=timeout,
            safe_mode=safe_mode,
            allow_any_variable=allow_any_variable,
            eol=eol,
        )

    def __enter__(self) -> MdcClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Close the connection."""
        self._stream.close()

    def run(self, op: Op[T]) -> T:
        """Run a generator op to completion over this connection."""
        io = self.core.run(op)
        try:
            step = next(io)
            while True:
                step = io.send(self._do(step))
        except StopIteration as done:
            result: T = done.value
            return result

    def _do(self, step: IoStep) -> bytes | None:
        if isinstance(step, Send):
            try:
                self._stream.write(step.data)
            except TransportTimeout:
                return None
            return b""
        self._stream.set_timeout(step.timeout)
        try:
            return self._stream.read(4096)
        except TransportTimeout:
            return None
        except PeerClosed:
            return b""

    def query(self, code: int, arg: int | None = None) -> Reply:
        """Send ``?Q<code>`` and return the typed reply."""
        return self.run(query_op(code, arg))

    def macro_get(self, var: int) -> float:
        """Read macro variable ``var``."""
        return self.run(macro_get_op(var))

    def macro_set(self, var: int, value: float) -> None:
        """Write macro variable ``var`` (refused while ``safe_mode`` is on).

        A write the control would refuse (:func:`opendnc.haas.macros.check_write`) raises
        :class:`~opendnc.errors.InputError` with the reason before anything is sent.
        """
        check_macro_write(
            var, value, safe_mode=self.safe_mode, allow_any_variable=self.allow_any_variable
        )
        self.run(macro_set_op(var, value))

    def status(self) -> MachineStatus:
        """One summary from all documented Q commands."""
        return self.run(status_op())


# --------------------------------------------------------------------------- asyncio


class AsyncMdcClient:
    """asyncio MDC client; same ops and the same :class:`MdcClientCore` as :class:`MdcClient`."""

    def __init__(
        self,
        reader: asyncio.StreamReader,
        writer: asyncio.StreamWriter,
        *,
        timeout: float = DEFAULT_TIMEOUT,
        safe_mode: bool = True,
        allow_any_variable: bool = False,
        eol: bytes = b"\r\n",
    ) -> None:
        self.safe_mode = safe_mode
        self.allow_any_variable = allow_any_variable
        self._reader, self._writer = reader, writer
        self.core = MdcClientCore(timeout=timeout, eol=eol)

    @classmethod
    async def connect(
        cls,
        host: str,
        port: int = DEFAULT_PORT,
        *,
        timeout: float = DEFAULT_TIMEOUT,
        safe_mode: bool = True,
        allow_any_variable: bool = False,
        eol: bytes = b"\r\n",
    ) -> AsyncMdcClient:
        """Open a TCP connection to the control."""
        try:
            reader, writer = await asyncio.wait_for(asyncio.open_connection(host, port), timeout)
        except TimeoutError as exc:
            raise TransportTimeout(f"connecting to {host}:{port} timed out") from exc
        except OSError as exc:
            raise TransportError(f"cannot connect to {host}:{port}: {os_reason(exc)}") from exc
        return cls(
            reader,
            writer,
            timeout=timeout,
            safe_mode=safe_mode,
            allow_any_variable=allow_any_variable,
            eol=eol,
        )

    async def __aenter__(self) -> AsyncMdcClient:
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    async def close(self) -> None:
        """Close the connection."""
        self._writer.close()
        with contextlib.suppress(OSError):  # the peer may already be gone
            await self._writer.wait_closed()

    async def run(self, op: Op[T]) -> T:
        """Run a generator op to completion over this connection."""
        io = self.core.run(op)
        try:
            step = next(io)
            while True:
                step = io.send(await self._do(step))
        except StopIteration as done:
            result: T = done.value
            return result

    async def _do(self, step: IoStep) -> bytes | None:
        # asyncio.timeout, not wait_for: wait_for wraps each read in a task of its own, and a
        # server polling hundreds of controls does this a few thousand times a second
        try:
            if isinstance(step, Send):
                self._writer.write(step.data)
                async with asyncio.timeout(step.timeout):
                    await self._writer.drain()
                return b""
            async with asyncio.timeout(max(step.timeout, ASYNC_WAITING)):
                return await self._reader.read(4096)
        except TimeoutError:
            return None
        except ConnectionResetError:
            return b""
        except OSError as exc:
            raise TransportError(f"MDC connection failed: {exc}") from exc

    async def query(self, code: int, arg: int | None = None) -> Reply:
        """Send ``?Q<code>`` and return the typed reply."""
        return await self.run(query_op(code, arg))

    async def macro_get(self, var: int) -> float:
        """Read macro variable ``var``."""
        return await self.run(macro_get_op(var))

    async def macro_set(self, var: int, value: float) -> None:
        """Write macro variable ``var`` (refused while ``safe_mode`` is on).

        A write the control would refuse (:func:`opendnc.haas.macros.check_write`) raises
        :class:`~opendnc.errors.InputError` with the reason before anything is sent.
        """
        check_macro_write(
            var, value, safe_mode=self.safe_mode, allow_any_variable=self.allow_any_variable
        )
        await self.run(macro_set_op(var, value))

    async def status(self) -> MachineStatus:
        """One summary from all documented Q commands."""
        return await self.run(status_op())
