"""MDC clients: blocking (:class:`MdcClient`) and asyncio (:class:`AsyncMdcClient`).

Every procedure is written once as a generator op (it yields requests and is sent the
matching replies) and run by either driver over the same :class:`~opendnc.haas.mdc.MdcConnection`.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Generator
from dataclasses import dataclass
from typing import Any, TypeVar

from opendnc.errors import (
    ControlRefused,
    PeerClosed,
    RemoteProtocolError,
    SafetyLockError,
    TransportError,
    TransportTimeout,
)
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
)
from opendnc.transport.tcp import TcpStream

T = TypeVar("T")
Op = Generator[Request, Reply, T]

DEFAULT_PORT = 5051


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


def _check_write(safe_mode: bool, var: int, allow_any: bool) -> None:
    if safe_mode:
        raise SafetyLockError(f"writing macro variable #{var} over MDC")
    if not allow_any and not is_writable(var):
        raise SafetyLockError(f"writing #{var} (not a general-purpose global; allow it explicitly)")


# --------------------------------------------------------------------------- blocking


class MdcClient:
    """Blocking MDC client over TCP (NGC, Setting 143 = port).

    ``safe_mode`` (default on) refuses :meth:`macro_set` with :class:`SafetyLockError`; with
    it off, writes are still limited to :data:`WRITABLE` unless ``allow_any_variable``.
    """

    def __init__(
        self,
        host: str,
        port: int = DEFAULT_PORT,
        *,
        timeout: float = 3.0,
        safe_mode: bool = True,
        allow_any_variable: bool = False,
        eol: bytes = b"\r\n",
    ) -> None:
        self.safe_mode = safe_mode
        self.allow_any_variable = allow_any_variable
        self._conn = MdcConnection(eol)
        self._stream = TcpStream(host, port, timeout=timeout)
        self._timeout = timeout
        self._first = True

    def __enter__(self) -> MdcClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Close the connection."""
        self._stream.close()

    def run(self, op: Op[T]) -> T:
        """Run a generator op to completion over this connection."""
        try:
            request = next(op)
            while True:
                reply = self._exchange(request)
                request = op.send(reply)
        except StopIteration as done:
            return done.value  # type: ignore[no-any-return]

    def _exchange(self, request: Request) -> Reply:
        # Haas: the very first query after connecting may go unanswered; ask once more.
        attempts = 2 if self._first else 1
        self._first = False
        for attempt in range(attempts):
            self._drain()
            self._stream.write(self._conn.send(request))
            try:
                while (reply := self._conn.next_event()) is None:
                    try:
                        data = self._stream.read(4096)
                    except PeerClosed:
                        data = b""
                    self._conn.receive_data(data)
                return reply
            except TransportTimeout:
                self._conn.reset()
                if attempt == attempts - 1:
                    raise
        raise AssertionError("unreachable")  # pragma: no cover

    def _drain(self) -> None:
        # Take in whatever other clients' broadcast replies are already waiting, so they
        # cannot be mistaken for the answer to the next request.
        self._stream.set_timeout(0.0)
        try:
            while True:
                self._conn.receive_data(self._stream.read(4096))
        except TransportError:
            pass  # nothing more waiting (a dead link shows up on the next write/read)
        finally:
            self._stream.set_timeout(self._timeout)

    def query(self, code: int, arg: int | None = None) -> Reply:
        """Send ``?Q<code>`` and return the typed reply."""
        return self.run(query_op(code, arg))

    def macro_get(self, var: int) -> float:
        """Read macro variable ``var``."""
        return self.run(macro_get_op(var))

    def macro_set(self, var: int, value: float) -> None:
        """Write macro variable ``var`` (refused while ``safe_mode`` is on)."""
        _check_write(self.safe_mode, var, self.allow_any_variable)
        self.run(macro_set_op(var, value))

    def status(self) -> MachineStatus:
        """One summary from all documented Q commands."""
        return self.run(status_op())


# --------------------------------------------------------------------------- asyncio


class AsyncMdcClient:
    """asyncio MDC client; same ops and engine as :class:`MdcClient`."""

    def __init__(
        self,
        reader: asyncio.StreamReader,
        writer: asyncio.StreamWriter,
        *,
        timeout: float = 3.0,
        safe_mode: bool = True,
        allow_any_variable: bool = False,
        eol: bytes = b"\r\n",
    ) -> None:
        self.safe_mode = safe_mode
        self.allow_any_variable = allow_any_variable
        self._reader, self._writer = reader, writer
        self._timeout = timeout
        self._conn = MdcConnection(eol)

    @classmethod
    async def connect(cls, host: str, port: int = DEFAULT_PORT, **kwargs: Any) -> AsyncMdcClient:
        """Open a TCP connection to the control."""
        timeout = float(kwargs.get("timeout", 3.0))
        try:
            reader, writer = await asyncio.wait_for(asyncio.open_connection(host, port), timeout)
        except TimeoutError as exc:
            raise TransportTimeout(f"connecting to {host}:{port} timed out") from exc
        except OSError as exc:
            raise TransportError(f"cannot connect to {host}:{port}: {exc}") from exc
        return cls(reader, writer, **kwargs)

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
        try:
            request = next(op)
            while True:
                reply = await self._exchange(request)
                request = op.send(reply)
        except StopIteration as done:
            return done.value  # type: ignore[no-any-return]

    async def _exchange(self, request: Request) -> Reply:
        try:
            with contextlib.suppress(TimeoutError):
                # take in other clients' broadcast replies already waiting (see MdcClient)
                while data := await asyncio.wait_for(self._reader.read(4096), 0.001):
                    self._conn.receive_data(data)
            self._writer.write(self._conn.send(request))
            await self._writer.drain()
            while (reply := self._conn.next_event()) is None:
                data = await asyncio.wait_for(self._reader.read(4096), self._timeout)
                self._conn.receive_data(data)
            return reply
        except TimeoutError as exc:
            self._conn.reset()
            raise TransportTimeout(f"no MDC reply to {request}") from exc
        except OSError as exc:
            raise TransportError(f"MDC connection failed: {exc}") from exc

    async def query(self, code: int, arg: int | None = None) -> Reply:
        """Send ``?Q<code>`` and return the typed reply."""
        return await self.run(query_op(code, arg))

    async def macro_get(self, var: int) -> float:
        """Read macro variable ``var``."""
        return await self.run(macro_get_op(var))

    async def macro_set(self, var: int, value: float) -> None:
        """Write macro variable ``var`` (refused while ``safe_mode`` is on)."""
        _check_write(self.safe_mode, var, self.allow_any_variable)
        await self.run(macro_set_op(var, value))

    async def status(self) -> MachineStatus:
        """One summary from all documented Q commands."""
        return await self.run(status_op())
