"""Drip-feed (DNC) a program to a Haas over RS-232, with XON/XOFF done by us.

The control runs blocks as they arrive and throttles the PC with flow control: it sends DC3
(XOFF, 0x13) when its small buffer is full and DC1 (XON, 0x11) when it has room again. Several
USB-serial drivers do not honour XOFF in the kernel (haas-protocols.md, section 3), so opendnc
implements it itself: bytes go out in small writes (``chunk``), every write is preceded by a
look at what the control sent, and nothing more is written after a DC3 until the DC1.

* :class:`DncStreamer` -- the sans-IO core: bytes to stream in, flow bytes in, small chunks out,
  a :class:`~opendnc.xmodem.events.Timer` for the XOFF timeout (the clock stays outside).
* :class:`ProgramFeed` -- the program from disk as wire lines, line by line (constant memory),
  optionally restarted at a line with :func:`opendnc.haas.modal.restart_preamble`.
* :func:`stream_program` -- the blocking driver over any pyserial port or URL.

Drip-feeding makes the machine move, so :func:`stream_program` refuses with
:class:`~opendnc.errors.SafetyLockError` unless ``safe_mode=False``.
"""

from __future__ import annotations

import enum
import os
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import serial

from opendnc.errors import (
    InputError,
    PeerClosed,
    SafetyLockError,
    TransportError,
    TransportTimeout,
)
from opendnc.haas.modal import ModalState, RestartPlan, restart_preamble, track
from opendnc.transport.serial import open_serial
from opendnc.xmodem.events import Timer
from opendnc.xmodem.haas import Eob

XON = 0x11  # DC1: resume
XOFF = 0x13  # DC3: pause


class Flow(enum.Enum):
    """Setting 14 (synchronisation) as the PC sees it."""

    XONXOFF = "xonxoff"  # we watch for DC3/DC1 ourselves
    RTSCTS = "rtscts"  # the port's hardware handshake holds our writes
    NONE = "none"


@dataclass(frozen=True, slots=True)
class DncConfig:
    """How to stream. ``chunk`` bounds how far we overrun a DC3 (plus the UART's own FIFO)."""

    flow: Flow = Flow.XONXOFF
    chunk: int = 16  # bytes per write
    xoff_timeout: float = 120.0  # give up if XOFF lasts longer (0 = wait forever)
    eob: Eob = Eob.LF
    drain: bool = True  # wait for each chunk to leave the port before the next check
    retract: bool = True  # restart preamble retracts Z (G91 G28 Z0.)
    # keep the port open this long after the last byte: closing a port can discard what a
    # USB adapter (or a pty) still holds, and the closing % must reach the control
    linger: float = 0.25


@dataclass(frozen=True, slots=True)
class Paused:
    """The control sent XOFF after ``sent`` bytes."""

    sent: int


@dataclass(frozen=True, slots=True)
class Resumed:
    """The control sent XON after ``sent`` bytes."""

    sent: int


DncEvent = Paused | Resumed


class DncStreamer:
    """Sans-IO flow control: ``queue()`` bytes, ``receive_data()`` what the control sends,
    write ``data_to_send()`` (empty while paused); call ``timed_out()`` when ``timer`` ran out.
    """

    def __init__(self, config: DncConfig | None = None) -> None:
        self.config = config or DncConfig()
        if self.config.chunk < 1:
            raise InputError("chunk must be at least 1 byte")
        self._out = bytearray()
        self._events: list[DncEvent] = []
        self._serial = 0
        self.timer: Timer | None = None
        self.paused = False
        self.sent = 0
        self.xoffs = 0
        self.xons = 0
        self.other = 0  # bytes from the control that are not flow control (NAK, DPRNT...)

    @property
    def pending(self) -> int:
        """Bytes queued but not handed out yet."""
        return len(self._out)

    def queue(self, data: bytes) -> None:
        """Add bytes to stream."""
        self._out += data

    def receive_data(self, data: bytes) -> None:
        """Bytes from the control: the last DC1/DC3 decides; anything else is counted."""
        if self.config.flow is not Flow.XONXOFF:
            self.other += len(data)
            return
        for byte in data:
            if byte == XOFF:
                self.xoffs += 1
                if not self.paused:
                    self.paused = True
                    self._events.append(Paused(self.sent))
                    if self.config.xoff_timeout > 0:
                        self._serial += 1
                        self.timer = Timer(self._serial, self.config.xoff_timeout)
            elif byte == XON:
                self.xons += 1
                if self.paused:
                    self.paused = False
                    self.timer = None
                    self._events.append(Resumed(self.sent))
            else:
                self.other += 1

    def data_to_send(self) -> bytes:
        """The next chunk to write (at most ``chunk`` bytes), or ``b""`` while paused."""
        if self.paused or not self._out:
            return b""
        size = self.config.chunk
        out = bytes(self._out[:size])
        del self._out[:size]
        self.sent += len(out)
        return out

    def timed_out(self) -> None:
        """The XOFF timer ran out: raise the typed error."""
        if self.paused and self.timer is not None:
            raise TransportTimeout(
                f"the control held XOFF for more than {self.config.xoff_timeout:g} s "
                f"after {self.sent} bytes (feed hold, alarm or a lost XON?)"
            )

    def next_event(self) -> DncEvent | None:
        """The next Paused/Resumed event, or ``None``."""
        return self._events.pop(0) if self._events else None


class ProgramFeed:
    """A program file as wire lines, read lazily; ``position`` is how far the file was read.

    The stream always starts with a ``%`` line and ends with one (added when the file lacks
    them). With ``from_line`` > 1 the lines before it are only scanned for their modal state,
    and the preamble from :func:`~opendnc.haas.modal.restart_preamble` replaces them.
    """

    def __init__(
        self,
        path: Path,
        *,
        eob: Eob = Eob.LF,
        from_line: int = 1,
        retract: bool = True,
    ) -> None:
        if from_line < 1:
            raise InputError(f"--from-line must be 1 or more, got {from_line}")
        try:
            self.total = path.stat().st_size
            self._file = path.open("rb")
        except OSError as exc:
            raise InputError(f"cannot read {path}: {exc.strerror or exc}") from exc
        self.path = path
        self.eob = eob
        self.from_line = from_line
        self.retract = retract
        self.position = 0
        self.lines = 0  # lines handed out (preamble included)
        self.plan: RestartPlan | None = None

    def close(self) -> None:
        """Close the file."""
        self._file.close()

    def _read_lines(self) -> Iterator[tuple[int, str]]:
        for number, raw in enumerate(self._file, start=1):
            self.position += len(raw)
            text = raw.rstrip(b"\r\n").decode("latin-1")
            if "\r" in text:  # old Mac-style files: CR only
                for part in text.split("\r"):
                    yield number, part
            else:
                yield number, text

    def __iter__(self) -> Iterator[bytes]:
        wire = self.eob.wire
        lines = self._read_lines()
        opened = False
        last = ""
        if self.from_line > 1:
            state = ModalState()
            for number, text in lines:
                if number >= self.from_line:
                    self.plan = restart_preamble(state, self.from_line, retract=self.retract)
                    for block in self.plan.preamble:
                        self.lines += 1
                        yield block.encode("latin-1") + wire
                    opened = True
                    if text.strip():
                        last = text.strip()
                        self.lines += 1
                        yield text.encode("latin-1") + wire
                    break
                state = track(state, text)
            else:
                raise InputError(f"{self.path} has fewer than {self.from_line} lines")
        for _number, text in lines:
            stripped = text.strip()
            if not stripped:
                continue  # empty blocks only waste the control's buffer
            if not opened:
                opened = True
                if stripped != "%":
                    self.lines += 1
                    yield b"%" + wire
            last = stripped
            self.lines += 1
            yield text.encode("latin-1") + wire
        if last != "%":
            self.lines += 1
            yield b"%" + wire


@dataclass(frozen=True, slots=True)
class DncReport:
    """What :func:`stream_program` did."""

    path: Path
    bytes_sent: int
    lines: int
    xoffs: int  # DC3 received
    xons: int  # DC1 received
    paused_seconds: float  # total time held by XOFF
    seconds: float
    restart: RestartPlan | None


Progress = Callable[[int, int], None]  # (file bytes consumed, file size)
EventHandler = Callable[[DncEvent], None]
POLL = 0.05


def _open(url: str, baud: int, parity: str, flow: Flow) -> Any:
    port = open_serial(url, baud, parity=parity, rtscts=flow is Flow.RTSCTS, timeout=POLL)
    # a held CTS must end in a clear error, not a hang
    port.write_timeout = 30.0
    return port


def stream_program(
    port: str | Any,
    path: Path,
    *,
    from_line: int = 1,
    baud: int = 9600,
    parity: str = "N",
    config: DncConfig | None = None,
    safe_mode: bool = True,
    progress: Progress | None = None,
    on_event: EventHandler | None = None,
    clock: Callable[[], float] = time.monotonic,
) -> DncReport:
    """Drip-feed ``path`` to a control in DNC mode over ``port`` (a URL or an open pyserial port).

    Raises :class:`SafetyLockError` while ``safe_mode`` is on (a DNC run moves the machine),
    :class:`TransportTimeout` when XOFF lasts longer than ``config.xoff_timeout``, and
    :class:`TransportError`/:class:`PeerClosed` when the port fails.
    """
    cfg = config or DncConfig()
    if safe_mode:
        raise SafetyLockError(f"drip-feeding {path.name} runs it on the machine")
    feed = ProgramFeed(path, eob=cfg.eob, from_line=from_line, retract=cfg.retract)
    owned = isinstance(port, str)
    try:
        link: Any = _open(port, baud, parity, cfg.flow) if isinstance(port, str) else port
    except BaseException:
        feed.close()
        raise
    streamer = DncStreamer(cfg)
    started = clock()
    paused_at = 0.0
    paused_total = 0.0
    deadline = float("inf")
    timer_serial = -1
    lines = iter(feed)
    exhausted = False
    low_water = cfg.chunk * 4
    try:
        while True:
            while not exhausted and streamer.pending < low_water:
                try:
                    streamer.queue(next(lines))
                except StopIteration:
                    exhausted = True
            waiting = link.in_waiting
            if waiting:
                streamer.receive_data(link.read(waiting))
            while (event := streamer.next_event()) is not None:
                if isinstance(event, Paused):
                    paused_at = clock()
                else:
                    paused_total += clock() - paused_at
                if on_event is not None:
                    on_event(event)
            out = streamer.data_to_send()
            if out:
                link.write(out)
                if cfg.drain:
                    link.flush()
                if progress is not None:
                    progress(feed.position, feed.total)
                continue
            if exhausted and streamer.pending == 0:
                break
            # paused: wait for the control, with the XOFF timer on our clock
            timer = streamer.timer
            if timer is not None and timer.serial != timer_serial:
                timer_serial, deadline = timer.serial, clock() + timer.seconds
            if timer is not None and clock() >= deadline:
                streamer.timed_out()
            data = link.read(1)
            if data:
                streamer.receive_data(data)
        link.flush()
        time.sleep(cfg.linger)
    except serial.SerialTimeoutException as exc:
        raise TransportTimeout(f"write to {path.name} port timed out (CTS held off?)") from exc
    except serial.SerialException as exc:
        raise PeerClosed(f"serial port failed during the drip-feed: {exc}") from exc
    except OSError as exc:
        raise TransportError(
            f"serial port failed during the drip-feed: {os.strerror(exc.errno or 0)}"
        ) from exc
    finally:
        feed.close()
        if owned:
            link.close()
    if progress is not None:
        progress(feed.total, feed.total)
    return DncReport(
        path=path,
        bytes_sent=streamer.sent,
        lines=feed.lines,
        xoffs=streamer.xoffs,
        xons=streamer.xons,
        paused_seconds=paused_total,
        seconds=clock() - started,
        restart=feed.plan,
    )
