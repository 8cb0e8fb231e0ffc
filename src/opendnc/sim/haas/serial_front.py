"""The virtual Haas's RS-232 port: XModem receive/punch, DNC drip-feed, DPRNT output.

On a real control the operator selects what the port does (receive into memory, punch a
program out, run DNC). Here that is :meth:`SerialFrontEnd.select` (Python) or
``opendnc sim haas --serial PORT --serial-mode MODE`` with MODE one of:

``receive``
    XModem receive into program memory (the control NAKs to start; see the quirks below).
``punch:O1000``
    XModem punch of a stored program: ``LF % LF O01000 ... LF LF % LF``, SUB padded.
``dnc``
    drip-feed: run plain text as it arrives, with XON/XOFF back-pressure from the block rate.
``dnc-xmodem``
    drip-feed by XModem: blocks are ACKed only when the buffer has room.
``auto``
    wait as an XModem receiver (NAKs); an XModem block stores a program, text (``%``) runs
    as DNC.
``idle``
    the port only carries DPRNT output.

A classic control with Setting 143 ON answers MDC Q and E commands on this port while it is
idle or waiting in ``auto`` mode (docs/haas.md#mdc): a ``?Q500`` line gets its reply framed
STX payload ETB CR LF ``>``, by the same :class:`~opendnc.sim.haas.mdc_server.MdcResponder`
the TCP server uses. In ``auto`` mode the first byte decides: an XModem block stores a
program, ``?`` is an MDC request, other text runs as DNC. An MDC exchange is no job: it
leaves no ``RS232 DONE`` message.

Receive, DNC and auto are re-armed after each job, punch runs once. Each job ends with
``RS232 DONE`` or ``RS232 ABORT ...`` in :attr:`SerialFrontEnd.messages`.

Haas XModem quirks (docs/xmodem.md#haas-dialect), each a knob of :class:`SerialOptions`: extra NAKs
with the start
requests, CAN CAN CAN answering the EOT of a complete transfer, and optionally ignoring the
PC's first NAK when punching. A DNC stream that breaks before its closing ``%`` (no data for
``dnc_timeout`` while the control waits for blocks, or the port closing) raises
:data:`~opendnc.sim.haas.control.ALARM_DNC_LINK`, visible as ``ALARM ON`` in Q500.

The port is served by one I/O thread (blocking pyserial, the blocking XModem driver); every
call into the control model is marshalled onto the simulator's event loop.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import dataclasses
import enum
import hashlib
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, TypeVar

import serial

from opendnc.errors import DncError, InputError, PeerClosed, TransportTimeout
from opendnc.haas import mdc
from opendnc.sim.haas.control import DncSession, DprntDestination
from opendnc.sim.haas.dnc_link import DncLimits, DncReceiver
from opendnc.sim.haas.dprnt_out import StreamDprntOutput
from opendnc.sim.haas.machine import Alarm
from opendnc.sim.haas.mdc_server import MdcResponder
from opendnc.sim.haas.serial_xmodem import (
    Interrupted,
    XmodemQuirks,
    punch_bytes,
    receive_xmodem,
    send_xmodem,
)
from opendnc.transport.serial import SerialStream
from opendnc.xmodem.haas import Eob, from_wire

if TYPE_CHECKING:
    from opendnc.sim.haas.app import SimHaas
    from opendnc.sim.haas.mdc_server import Trace

T = TypeVar("T")

ALARM_DNC_OVERRUN = Alarm(1004, "DNC BUFFER OVERRUN")
"""The sender ignored XOFF and overflowed the DNC buffer (simulator's own number)."""

POLL = 0.05
ERROR_BACKOFF = 0.5  # seconds before a failed job is re-armed
MDC_QUIET = 0.3
"""Seconds of silence after an MDC exchange before ``auto`` waits for XModem again (a poll's
next query usually follows within that time, so it is not preceded by the receiver's NAK)."""
MDC_LINE_TIMEOUT = 1.0  # seconds a started request line may take to end
_LEADER = b"\x00\r\n \x11\x13\x15"  # what may precede a request (NUL, blanks, XON/XOFF, NAK)


class SerialMode(enum.Enum):
    """What the operator selected for the serial port."""

    IDLE = "idle"
    RECEIVE = "receive"
    PUNCH = "punch"
    DNC = "dnc"
    DNC_XMODEM = "dnc-xmodem"
    AUTO = "auto"


@dataclass(frozen=True, slots=True)
class Selection:
    """A mode and, for PUNCH, the program number."""

    mode: SerialMode
    program: int | None = None


def parse_mode(spec: str) -> Selection:
    """``receive`` | ``punch:O1000`` | ``dnc`` | ``dnc-xmodem`` | ``auto`` | ``idle``."""
    kind, _, arg = spec.strip().lower().partition(":")
    try:
        mode = SerialMode(kind)
    except ValueError:
        raise InputError(
            f"bad serial mode {spec!r}: use receive, punch:O<n>, dnc, dnc-xmodem, auto or idle"
        ) from None
    if mode is SerialMode.PUNCH:
        digits = arg.lstrip("o")
        if not digits.isdigit() or not 0 < int(digits) <= 99999:
            raise InputError(f"bad serial mode {spec!r}: punch needs a program, e.g. punch:O1000")
        return Selection(mode, int(digits))
    if arg:
        raise InputError(f"bad serial mode {spec!r}: {kind} takes no argument")
    return Selection(mode)


@dataclass(frozen=True, slots=True)
class SerialOptions:
    """Port settings (Settings 11, 12, 25) and the behaviour knobs of the serial front-end."""

    baud: int = 9600
    parity: str = "N"
    eob: Eob = Eob.LF
    mode: Selection = field(default_factory=lambda: Selection(SerialMode.AUTO))
    quirks: XmodemQuirks = field(default_factory=XmodemQuirks)
    limits: DncLimits = field(default_factory=DncLimits)
    dnc_timeout: float = 10.0  # silence (while waiting for blocks) that means a broken link
    xon_at_start: bool = True  # DNC: announce readiness with DC1
    dprnt_eol: bytes = b"\r"  # Haas documents CR after each DPRNT block
    # The operator's part of a punch-back check (docs/xmodem.md#end-to-end-checks): after each
    # program received by XModem, punch it out again, then return to the mode before.
    punch_back: bool = False


class _Abort(DncError):
    """A job ended without success (the message goes to ``messages``)."""


class SerialFrontEnd:
    """The serial port of a :class:`~opendnc.sim.haas.app.SimHaas` (see the module docstring)."""

    def __init__(
        self, sim: SimHaas, url: str, options: SerialOptions, trace: Trace | None = None
    ) -> None:
        self.sim = sim
        self.control = sim.control
        self.url = url
        self.options = options
        self.trace = trace
        self.messages: list[str] = []
        self.programs: list[int] = []  # O numbers received into memory, in order
        self.dnc_lines = 0  # blocks handed to the control by DNC runs
        # a running SHA-256 of those blocks, each with LF after it: a test compares what the
        # control got, across feeds and servers, with the program once in order
        self.dnc_sha256 = hashlib.sha256()
        # The first DNC_HEAD blocks of every DNC run, so a test can see how a run began
        # (a restart's preamble); bounded, as a run may be megabytes long.
        self.dnc_heads: list[list[str]] = []
        self.xoffs = 0
        self.xons = 0
        self.jobs_done = 0
        self.mdc_replies = 0  # MDC requests answered on this port (classic Setting 143)
        self.port: SerialStream | None = None
        self._mdc = MdcResponder(sim.control)
        self._loop: asyncio.AbstractEventLoop | None = None
        self._jobs: queue.Queue[Selection] = queue.Queue()
        self._current = options.mode
        self._stop = threading.Event()
        self._interrupt = threading.Event()
        self._write_lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self.idle = threading.Event()
        # called (on the I/O thread) with each RS232 DONE / RS232 ABORT message
        self.on_message: Callable[[str], None] | None = None

    # --------------------------------------------------------------- lifecycle
    async def start(self) -> None:
        """Open the port, attach the serial DPRNT output and start serving."""
        self._loop = asyncio.get_running_loop()
        opts = self.options
        self.port = SerialStream(
            self.url, opts.baud, parity=opts.parity, bytesize=8, stopbits=1, timeout=POLL
        )
        self.control.machine.settings[11] = opts.baud
        self.control.machine.settings[25] = opts.eob.value.upper()
        output = StreamDprntOutput(self.write, eol=opts.dprnt_eol)
        self.control.attach_dprnt(DprntDestination.SERIAL, output)
        self._thread = threading.Thread(target=self._serve, name="opendnc-haas-serial", daemon=True)
        self._thread.start()

    async def close(self) -> None:
        """Stop serving and close the port."""
        self._stop.set()
        self._interrupt.set()
        if self._thread is not None:
            # the thread reads with a short timeout and sees the stop flag within a poll
            await asyncio.get_running_loop().run_in_executor(None, self._thread.join, 5.0)
        if self.port is not None:
            with self._write_lock:
                self.port.close()

    def select(self, mode: SerialMode | str, program: int | None = None) -> None:
        """Operator key press: make the port do ``mode`` once the current job has ended."""
        selection = parse_mode(mode) if isinstance(mode, str) else Selection(mode, program)
        if selection.mode is SerialMode.PUNCH and selection.program is None:
            raise InputError("punch needs a program number")
        self._jobs.put(selection)
        self._interrupt.set()  # a job still waiting for the PC gives way

    def write(self, data: bytes) -> None:
        """Write to the port from any thread (DPRNT output, flow control, XModem)."""
        if self.port is None or self._stop.is_set():
            return
        if self.trace is not None:
            self.trace("tx", data)
        with self._write_lock, contextlib.suppress(DncError):
            self.port.write(data)

    # --------------------------------------------------------------- loop marshalling
    def call(self, func: Callable[[], T]) -> T:
        """Run ``func`` on the simulator's loop and wait for its result."""
        assert self._loop is not None
        future: concurrent.futures.Future[T] = concurrent.futures.Future()

        def run() -> None:
            try:
                future.set_result(func())
            except BaseException as exc:  # handed back to the caller's thread
                future.set_exception(exc)

        try:
            self._loop.call_soon_threadsafe(run)
        except RuntimeError as exc:  # the loop is already closed
            raise TransportTimeout("the simulator's event loop has stopped") from exc
        try:
            return future.result(10.0)
        except concurrent.futures.TimeoutError as exc:
            raise TransportTimeout("the simulator's event loop did not answer") from exc

    def post(self, func: Callable[[], object]) -> None:
        """Run ``func`` on the simulator's loop, in order with other posts, without waiting."""
        assert self._loop is not None
        self._loop.call_soon_threadsafe(func)

    # --------------------------------------------------------------- MDC (Setting 143)
    def mdc_enabled(self) -> bool:
        """Classic control with Setting 143 ON: Q and E commands are answered on this port."""
        control = self.control
        return control.control_type is mdc.ControlType.CLASSIC and bool(
            control.machine.settings.get(143)
        )

    def _serve_mdc(self, first: bytes) -> None:
        """Answer MDC requests from ``first`` on, until the line has been quiet a while."""
        assert self.port is not None
        self.port.set_timeout(POLL)
        pending = first
        quiet_since = time.monotonic()
        line_started = 0.0
        while not self._stop.is_set():
            data = pending.translate(None, mdc.LINE_NOISE)
            if data:
                self._answer_mdc(data)
                quiet_since = time.monotonic()
                partial = not data.endswith((b"\r", b"\n"))
                line_started = (line_started or quiet_since) if partial else 0.0
            now = time.monotonic()
            if line_started and now - line_started > MDC_LINE_TIMEOUT:
                # a request that never ends is garbage: answer it so rather than wait for ever
                self._answer_mdc(b"\n")
                line_started = 0.0
            if not line_started and (now - quiet_since > MDC_QUIET or self._interrupt.is_set()):
                return
            try:
                pending = self._read_chunk()
            except PeerClosed:
                return

    def _answer_mdc(self, data: bytes) -> None:
        # the responder reads and writes the control's state: on the simulator's loop
        replies = self.call(lambda: self._mdc.feed(data))
        for reply in replies:
            self.write(reply)
        self.mdc_replies += len(replies)

    def _idle_mdc(self) -> None:
        """Idle port with Setting 143 ON: wait one poll period for a request."""
        assert self.port is not None
        self.port.set_timeout(POLL)
        try:
            data = self._read_chunk()
        except PeerClosed:
            self._stop.wait(ERROR_BACKOFF)
            return
        if data.lstrip(_LEADER).startswith(b"?") and self.mdc_enabled():
            self._serve_mdc(data)

    # --------------------------------------------------------------- the I/O thread
    def _serve(self) -> None:
        while not self._stop.is_set():
            self._interrupt.clear()
            with contextlib.suppress(queue.Empty):
                self._current = self._jobs.get_nowait()
            selection = self._current
            if selection.mode is SerialMode.IDLE:
                self.idle.set()
                if self.mdc_enabled():
                    self._idle_mdc()
                    continue
                with contextlib.suppress(queue.Empty):
                    self._current = self._jobs.get(timeout=POLL)
                continue
            self.idle.clear()
            try:
                if not self._run_job(selection):
                    continue  # an MDC exchange, not a job
                self._message("RS232 DONE")
            except Interrupted:
                continue
            except DncError as exc:
                if self._stop.is_set():
                    return
                self._message(f"RS232 ABORT {exc}")
                # a dead port fails every job at once: re-arm slowly instead of spinning
                self._stop.wait(ERROR_BACKOFF)
            self.jobs_done += 1
            if selection.mode is SerialMode.PUNCH and self._current is selection:
                self._current = Selection(SerialMode.IDLE)

    def _message(self, text: str) -> None:
        self.messages.append(text)
        if self.on_message is not None:
            self.on_message(text)
        if self.trace is not None:
            self.trace("rx", f"[{text}]".encode())

    def _run_job(self, selection: Selection) -> bool:
        """Run one job; False when ``auto`` found an MDC request instead (answered, no job)."""
        mode = selection.mode
        assert self.port is not None
        xmodem = mode in (SerialMode.PUNCH, SerialMode.RECEIVE, SerialMode.DNC_XMODEM)
        if xmodem and self.options.parity.upper() != "N":
            # Haas: XMODEM needs parity None and 8 data bits
            self._stop.wait(ERROR_BACKOFF)
            raise _Abort("XMODEM needs parity N (Setting 12)")
        if mode is SerialMode.PUNCH:
            assert selection.program is not None
            number = selection.program
            text = self.call(lambda: self.control.read_program(number))
            wire = punch_bytes(text, self.options.eob)
            send_xmodem(self.port, self.write, wire, self.options, self._interrupt, self._stop)
        elif mode is SerialMode.RECEIVE:
            data = receive_xmodem(
                self.port, self.write, self.options, interrupt=self._interrupt, stop=self._stop
            )
            if isinstance(data, bytes):
                self._store(data, selection)
        elif mode is SerialMode.AUTO:
            got = receive_xmodem(
                self.port,
                self.write,
                self.options,
                text_ok=True,
                interrupt=self._interrupt,
                stop=self._stop,
            )
            if isinstance(got, bytes):
                self._store(got, selection)
            elif self.mdc_enabled() and got.text.lstrip(_LEADER).startswith(b"?"):
                self._serve_mdc(got.text)
                return False
            else:
                self._dnc(first=got.text)
        elif mode is SerialMode.DNC:
            self._dnc(first=b"")
        elif mode is SerialMode.DNC_XMODEM:
            self._dnc_xmodem()
        return True

    def _store(self, data: bytes, selection: Selection) -> None:
        text = from_wire(data, self.options.eob).decode("latin-1")
        number = self.call(lambda: self.control.save_program(text))
        self.programs.append(number)
        if self.options.punch_back:
            # what the memory now holds goes out as the control punches it (a damaged load
            # comes back damaged), then the port returns to what it was doing
            self._jobs.put(Selection(SerialMode.PUNCH, number))
            self._jobs.put(selection)

    # --------------------------------------------------------------- DNC
    def _dnc(self, first: bytes) -> None:
        run = _DncRun(self)
        if self.options.xon_at_start:
            self.write(b"\x11")
        run.take(first)
        last_data = time.monotonic()
        assert self.port is not None
        while not run.ended:
            if run.receiver.xoff:
                # silence is expected now; wake often so the DC1 follows the drain closely
                # (a blocking read would only return after a whole poll period)
                last_data = time.monotonic()
                if not self._input_waiting():
                    time.sleep(0.001)
                    run.update_flow()
                    if self._stop.is_set():
                        return
                    continue
            try:
                data = self._read_chunk()
            except PeerClosed as exc:
                run.link_lost(f"port closed: {exc}")
                raise _Abort("DNC link lost (port closed)") from exc
            now = time.monotonic()
            if data:
                last_data = now
                run.take(data)
            else:
                run.update_flow()
                if run.starved() and now - last_data > self.options.dnc_timeout:
                    run.link_lost(f"no data for {self.options.dnc_timeout:g} s")
                    raise _Abort("DNC link lost (timeout)")
            if self._stop.is_set():
                return
            if self._interrupt.is_set() and run.session is None:
                raise Interrupted("another serial mode was selected")
        run.wait_finished(self._stop)

    def _read_chunk(self) -> bytes:
        """Up to 4 KiB of a drip-feed; ``b""`` after a poll period without data.

        Reads the pyserial port directly: its ``in_waiting`` is exact on a device or pty, but
        only 0/1 on ``socket://``, where a full-size read (ended by the port timeout) keeps a
        streamed program from trickling in two bytes per call.
        """
        assert self.port is not None
        port = self.port.port
        try:
            waiting = int(getattr(port, "in_waiting", 0))
            return bytes(port.read(waiting if waiting > 1 else 4096))
        except (serial.SerialException, OSError) as exc:
            raise PeerClosed(f"{self.url}: {exc}") from exc

    def _input_waiting(self) -> bool:
        port = self.port.port if self.port is not None else None
        try:
            return bool(getattr(port, "in_waiting", 1))
        except (OSError, serial.SerialException):
            return True  # let the read report the failure

    def _dnc_xmodem(self) -> None:
        run = _DncRun(self)
        assert self.port is not None

        def on_data(data: bytes) -> None:
            run.take(data)
            # hold the ACK (the driver writes it after this returns) while the buffer is full
            while run.backlog() > run.receiver.limits.resume_blocks and not run.session_done():
                if self._stop.is_set():
                    return
                time.sleep(0.005)

        try:
            receive_xmodem(
                self.port,
                self.write,
                self.options,
                on_data=on_data,
                interrupt=self._interrupt,
                stop=self._stop,
            )
        except Interrupted:
            raise
        except DncError:
            run.link_lost("XModem DNC stream broken")
            raise
        if not run.ended:
            run.link_lost("XModem DNC stream ended before the closing %")
            raise _Abort("XModem DNC stream ended before the closing %")
        run.wait_finished(self._stop)


DNC_HEAD = 50  # blocks of each DNC run kept in SerialFrontEnd.dnc_heads


class _DncRun:
    """One DNC run seen from the I/O thread: blocks go to the control, flow bytes to the PC."""

    def __init__(self, front: SerialFrontEnd) -> None:
        self.front = front
        self.receiver = DncReceiver(front.options.limits)
        self.session: DncSession | None = None
        self.fed = 0
        self.ended = False
        self._name: str | None = None

    def backlog(self) -> int:
        session = self.session
        # runner.index is read across threads: a plain int, a stale value only delays a DC1
        return self.fed - session.runner.index if session is not None else 0

    def session_done(self) -> bool:
        return self.session is not None and self.session.runner.finished

    def starved(self) -> bool:
        """A run waits for blocks (only then does silence mean a broken link)."""
        return self.session is not None and (self.backlog() <= 0 or self.session_done())

    def take(self, data: bytes) -> None:
        front = self.front
        try:
            blocks = self.receiver.receive_data(data)
        except DncError as exc:
            self.link_lost(str(exc))
            raise _Abort(str(exc)) from exc
        if blocks and self.session is None:
            first = blocks[0]
            name = first.split("(")[0].strip() if first[:1] in "Oo" else "DNC"
            self.session = front.call(lambda: front.control.start_dnc(name.upper() or "DNC"))
            if first[:1] in "Oo":
                blocks = blocks[1:]
        if self.session_done() and not self.ended and self.front.control.machine.alarms:
            raise _Abort("the DNC run stopped at the control (alarm or reset)")
        # after M30 the run is over; what follows up to the closing % is read and dropped
        session = self.session
        if blocks and session is not None:
            closing = blocks[-1] == "%"
            body = blocks[:-1] if closing else blocks

            def feed() -> None:
                if session.source.complete or session.runner.finished:
                    return
                for line in body:
                    session.feed_line(line)
                if closing:
                    session.finish()

            front.post(feed)
            if self.fed == 0:
                front.dnc_heads.append([])
            head = front.dnc_heads[-1]
            head += body[: max(0, DNC_HEAD - len(head))]
            self.fed += len(body)
            for line in body:
                front.dnc_sha256.update(line.encode("latin-1") + b"\n")
            front.dnc_lines += len(body)
            if closing:
                self.ended = True
        if self.receiver.overrun(self.backlog()) and session is not None:
            front.post(lambda: front.control.raise_alarm(ALARM_DNC_OVERRUN, "XOFF ignored"))
            raise _Abort("DNC buffer overrun: the sender ignored XOFF")
        self.update_flow()

    def update_flow(self) -> None:
        byte = self.receiver.flow(self.backlog())
        if byte:
            self.front.write(byte)
            if byte == b"\x13":
                self.front.xoffs += 1
            else:
                self.front.xons += 1

    def link_lost(self, detail: str) -> None:
        """Alarm (ALARM_DNC_LINK) if a run had started; a link idle between runs is no fault."""
        session = self.session
        if session is not None:
            self.front.post(lambda: session.link_lost(detail))

    def wait_finished(self, stop: threading.Event) -> None:
        """After the closing %: keep the port quiet until the run has executed every block."""
        while self.session is not None and not self.session.runner.finished:
            if stop.wait(0.01):
                return
        if self.session is not None and self.front.control.machine.alarms:
            raise _Abort("the DNC run ended with an alarm")


async def start_serial(
    sim: SimHaas,
    url: str,
    baud: int = 9600,
    trace: Trace | None = None,
    options: SerialOptions | None = None,
) -> SerialFrontEnd:
    """Open ``url`` as the control's serial port (the CLI's ``--serial``); ``baud`` wins."""
    opts = options or SerialOptions()
    if opts.baud != baud:
        opts = dataclasses.replace(opts, baud=baud)
    front = SerialFrontEnd(sim, url, opts, trace)
    await front.start()
    return front
