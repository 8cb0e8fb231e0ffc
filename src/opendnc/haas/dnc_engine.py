"""The sans-IO drip-feed engine: program lines in, small chunks out, XON/XOFF obeyed.

The control runs blocks as they arrive and throttles the PC with flow control: it sends DC3
(XOFF, 0x13) when its small buffer is full and DC1 (XON, 0x11) when it has room again. Several
USB-serial drivers do not honour XOFF in the kernel (docs/haas.md#flow-control), so opendnc
implements it itself: bytes go out in small writes (``chunk``), every write is preceded by a
look at what the control sent, and nothing more is written after a DC3 until the DC1.

* :class:`DncStreamer` -- flow control alone: bytes to stream in, flow bytes in, small chunks
  out, a :class:`~opendnc.xmodem.events.Timer` for the XOFF timeout (the clock stays outside).
* :class:`ProgramFeed` -- the program from disk as wire lines, line by line (constant memory),
  optionally restarted at a line with :func:`opendnc.haas.modal.restart_preamble`.
* :class:`DncRun` -- one whole run: feed, streamer, clock and accounting. A driver asks it for
  the :meth:`~DncRun.next_step` (:class:`Send`, :class:`Drain`, :class:`Wait` or
  :class:`Finish`), does it and hands back what the control sent. The drivers in
  :mod:`opendnc.haas.dnc` (blocking, over a :class:`~opendnc.transport.base.PortStream`;
  asyncio, over stream reader and writer) hold no decisions of their own.
"""

from __future__ import annotations

import enum
import time
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

from opendnc.errors import InputError, PeerClosed, TransportTimeout
from opendnc.haas.modal import ModalState, RestartPlan, restart_preamble, track
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
    # keep the port open until the control's flow bytes have stopped for this long after the
    # last byte: closing a port can discard what a USB adapter (or a pty) still holds, and
    # over TCP an XON or XOFF arriving after we closed resets the connection, which loses
    # what the serial server still holds of the program (docs/ports.md). Bounded by
    # xoff_timeout.
    linger: float = 0.25
    # start only after the control's first DC1 (it announces readiness), as DNC packages offer
    wait_for_xon: bool = False
    # refuse a file that is not NC program text before the first byte (opendnc.nctext)
    text_check: bool = True
    # tape leader and trailer: bytes sent before the opening % and after the closing one
    # (NULs, as a paper tape's feed holes; controls skip them before the %)
    leader: bytes = b""
    trailer: bytes = b""
    # seconds of silence after each line has left the port, for controls whose small
    # receive buffer overruns without a handshake (docs/server.md#serial-profile)
    line_delay: float = 0.0


@dataclass(frozen=True, slots=True)
class Paused:
    """The control sent XOFF after ``sent`` bytes."""

    sent: int


@dataclass(frozen=True, slots=True)
class Resumed:
    """The control sent XON after ``sent`` bytes."""

    sent: int


DncEvent = Paused | Resumed


@dataclass(frozen=True, slots=True)
class FeedPosition:
    """Where a stopped drip-feed is, exactly: the file offset at which the program's next
    line starts (every line before it reached the control whole) and the wire bytes of that
    line (or of the closing ``%``) the control already has, since an XOFF can stop a feed in
    the middle of a line. A continuation reads the file from ``offset``, leaves out
    ``written`` and sends the rest: no leader, no opening ``%``, nothing twice."""

    offset: int
    written: bytes = b""


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
        if self.config.wait_for_xon and self.config.flow is Flow.XONXOFF:
            self.paused = True
            self._arm()
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
                    self._arm()
            elif byte == XON:
                self.xons += 1
                if self.paused:
                    self.paused = False
                    self.timer = None
                    self._events.append(Resumed(self.sent))
            else:
                self.other += 1

    def _arm(self) -> None:
        if self.config.xoff_timeout > 0:
            self._serial += 1
            self.timer = Timer(self._serial, self.config.xoff_timeout)

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
            if self.sent == 0 and self.xons == 0 and self.config.wait_for_xon:
                raise TransportTimeout(
                    f"no XON from the control within {self.config.xoff_timeout:g} s "
                    "(is it waiting in DNC mode?)"
                )
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
        resume_at: int | None = None,
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
        # A continuation (FeedPosition.offset): the program's opening went out before, so
        # reading starts at that line, with no "%" and no preamble in front of it.
        self.resume_at = resume_at
        self._before = ""  # the last non-blank line before resume_at (is a closing % owed?)
        if resume_at is not None:
            if not 0 <= resume_at <= self.total:
                self._file.close()
                raise InputError(f"{path.name}: no position {resume_at} in {self.total} bytes")
            head = self._file.read(resume_at)
            if head and not head.endswith(b"\n"):
                self._file.close()
                raise InputError(f"{path.name}: position {resume_at} is not the start of a line")
            kept = [t.strip() for t in head.decode("latin-1").splitlines() if t.strip()]
            self._before = kept[-1] if kept else ""
            self.position = self.done_at = resume_at
        # What the item last handed out is: "open" (an added opening %), "preamble" (a
        # restart's), "line" (a program line), "close" (an added closing %): a position is
        # only exact after an opening or a program line.
        self.kind = ""
        # a line with CR-only ends was split: its parts share one offset, so no offset says
        # where within it a run stopped
        self.cr_split = False
        # File offset up to which every line is out once the line last yielded is out: what
        # a run stopped there has done (a restart from the next line skips and repeats
        # nothing). The preamble of a restart has done none of its own line.
        self.done_at = 0
        self.lines = 0  # lines handed out (preamble included)
        self.plan: RestartPlan | None = None

    def close(self) -> None:
        """Close the file."""
        self._file.close()

    def _read_lines(self) -> Iterator[tuple[int, str, int]]:
        """(line number, text, offset done once this text is out)."""
        for number, raw in enumerate(self._file, start=1):
            start = self.position
            self.position += len(raw)
            text = raw.rstrip(b"\r\n").decode("latin-1")
            if "\r" in text:  # old Mac-style files: CR only
                self.cr_split = True
                *parts, last = text.split("\r")
                for part in parts:
                    yield number, part, start
                yield number, last, self.position
            else:
                yield number, text, self.position

    def __iter__(self) -> Iterator[bytes]:
        wire = self.eob.wire
        lines = self._read_lines()
        opened = self.resume_at is not None
        last = self._before
        if self.from_line > 1 and self.resume_at is None:
            state = ModalState()
            before = 0
            for number, text, done in lines:
                if number >= self.from_line:
                    self.plan = restart_preamble(state, self.from_line, retract=self.retract)
                    self.done_at = before
                    self.kind = "preamble"
                    for block in self.plan.preamble:
                        self.lines += 1
                        yield block.encode("latin-1") + wire
                    opened = True
                    self.done_at = done
                    if text.strip():
                        last = text.strip()
                        self.lines += 1
                        self.kind = "line"
                        yield text.encode("latin-1") + wire
                    break
                before = done
                state = track(state, text)
            else:
                raise InputError(f"{self.path} has fewer than {self.from_line} lines")
        for _number, text, done in lines:
            stripped = text.strip()
            if not stripped:
                self.done_at = done
                continue  # empty blocks only waste the control's buffer
            if not opened:
                opened = True
                if stripped != "%":
                    self.lines += 1
                    self.kind = "open"
                    yield b"%" + wire
            last = stripped
            self.done_at = done
            self.lines += 1
            self.kind = "line"
            yield text.encode("latin-1") + wire
        self.done_at = self.position
        if last != "%":
            self.lines += 1
            self.kind = "close"
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
Clock = Callable[[], float]
POLL = 0.05


@dataclass(frozen=True, slots=True)
class Send:
    """Write ``data``; with ``drain``, wait until it left the port before the next step."""

    data: bytes
    drain: bool


@dataclass(frozen=True, slots=True)
class Wait:
    """Paused by XOFF: wait up to ``seconds`` for the control's bytes, then ask again."""

    seconds: float


@dataclass(frozen=True, slots=True)
class Drain:
    """Everything was handed out: wait until it has left the port."""


@dataclass(frozen=True, slots=True)
class Finish:
    """The control is done with the link (quiet for ``linger`` s after the end): close it."""


Step = Send | Drain | Wait | Finish


class DncRun:
    """One drip-feed as every driver runs it: feed, streamer, clock-side timer, accounting.

    A driver loops on :meth:`next_step` and does what it says, hands every byte the control
    sends to :meth:`incoming` (before each write, where it can look without waiting), calls
    :meth:`link_closed` when the control hung up, and ends with :meth:`report`.
    """

    def __init__(
        self,
        feed: ProgramFeed,
        config: DncConfig,
        *,
        clock: Clock = time.monotonic,
        progress: Progress | None = None,
        on_event: EventHandler | None = None,
        skip: bytes = b"",
        waiting: Callable[[], None] | None = None,
    ) -> None:
        self.feed = feed
        self.config = config
        # a continuation: these first bytes of the stream reached the control before (its
        # FeedPosition.written), checked against the program and not sent again
        self.skip = skip
        # set by a driver while a write or drain is under way: a run stopped then may have
        # left the control more than ``sent`` says, so it has no exact position
        self.writing = False
        self.streamer = DncStreamer(config)
        self.clock = clock
        self.progress = progress
        # asked before every wait for the control (held by XOFF, a line's delay): it may
        # raise to stop the run there, between two writes, where its position is exact (a
        # feed that must stop need not wait for a DC1 to notice, nor for its link to close)
        self.waiting = waiting
        self.on_event = on_event
        self.started = clock()
        self._lines = self._wire()
        self._exhausted = False
        self._low_water = config.chunk * 4
        self._paused_at = self.started  # counts when waiting for the first XON
        self._paused_total = 0.0
        self._timer_serial = -1
        self._deadline = float("inf")
        self._closed = False
        self._done_at: float | None = None  # when the last byte was handed out
        self._heard_at = self.started  # when the control last sent XON or XOFF
        self._gap_due = False  # a line just went out whole: its line delay starts next step
        self._gap_until = self.started  # no line before this time (the line delay)
        self._queued = 0  # bytes queued to the streamer so far
        # (queued bytes at the end of a line, the feed's done_at for it, what the line was),
        # oldest first: what progress reports once the streamer has handed those bytes out
        self._marks: deque[tuple[int, int, str]] = deque()
        self._whole: tuple[int, int, str] | None = None  # the last mark handed out whole
        self._reported = -1

    def _wire(self) -> Iterator[bytes]:
        if self.skip or self.feed.resume_at is not None:
            yield from self._continued()
            return
        if self.config.leader:
            self.feed.kind = "leader"
            yield self.config.leader
        yield from self.feed
        if self.config.trailer:
            self.feed.kind = "trailer"
            yield self.config.trailer

    def _continued(self) -> Iterator[bytes]:
        """The stream of a continuation: no leader; the bytes the control has are left out."""

        def rest() -> Iterator[bytes]:
            yield from self.feed
            if self.config.trailer:
                self.feed.kind = "trailer"
                yield self.config.trailer

        left = self.skip
        for item in rest():
            if left:
                n = min(len(left), len(item))
                if item[:n] != left[:n]:
                    raise InputError(
                        f"{self.feed.path.name}: the bytes the control has at this position "
                        "are not this program's"
                    )
                left, item = left[n:], item[n:]
                if not item:
                    continue
            yield item
        if left:
            raise InputError(f"{self.feed.path.name}: the position is past the program's end")

    def fill(self) -> None:
        """Read program lines until a few chunks are queued (constant memory); with a line
        delay, one line at a time and only once the delay after the previous one is over."""
        streamer = self.streamer
        if self.config.line_delay > 0:
            if streamer.pending or self._exhausted or self.clock() < self._gap_until:
                return
            self._queue_line()
            return
        while not self._exhausted and streamer.pending < self._low_water:
            self._queue_line()

    def _queue_line(self) -> None:
        try:
            line = next(self._lines)
        except StopIteration:
            self._exhausted = True
            return
        self.streamer.queue(line)
        self._queued += len(line)
        self._marks.append((self._queued, self.feed.done_at, self.feed.kind))

    def _report_progress(self) -> None:
        """Progress for the lines the driver has written whole (it calls :meth:`next_step`
        after doing each step): reported after the write, never for bytes still queued, so a
        run stopped from the callback names the first line the control did not get whole."""
        done = None
        while self._marks and self._marks[0][0] <= self.streamer.sent:
            self._whole = self._marks.popleft()
            done = self._whole[1]
        if done is not None and done != self._reported and self.progress is not None:
            self._reported = done
            self.progress(done, self.feed.total)

    @property
    def finished(self) -> bool:
        """Every byte of the program was handed out."""
        return self._exhausted and self.streamer.pending == 0

    def incoming(self, data: bytes) -> None:
        """Bytes from the control (flow control, or anything else it sends)."""
        if not data:
            return
        flow_bytes = self.streamer.xoffs + self.streamer.xons
        self.streamer.receive_data(data)
        if self.streamer.xoffs + self.streamer.xons != flow_bytes:
            self._heard_at = self.clock()
        while (event := self.streamer.next_event()) is not None:
            if isinstance(event, Paused):
                self._paused_at = self.clock()
            else:
                self._paused_total += self.clock() - self._paused_at
            if self.on_event is not None:
                self.on_event(event)

    def outgoing(self) -> bytes:
        """The next chunk to write (empty while paused or when done)."""
        self.fill()
        out = self.streamer.data_to_send()
        if out and self.config.line_delay > 0 and not self.streamer.pending:
            self._gap_due = True
        return out

    def link_closed(self) -> None:
        """The control closed the link: the next step that would wait for it raises."""
        self._closed = True

    def next_step(self) -> Step:
        """What the driver does next. Raises :class:`TransportTimeout` once XOFF lasted too
        long and :class:`PeerClosed` once the control closed the link before the end."""
        self._report_progress()
        if self._closed:
            self.fill()
            if not self.finished:
                raise PeerClosed(f"the control closed the link after {self.streamer.sent} bytes")
        if self._gap_due:
            # The driver has written (and drained) the line's last chunk: the delay runs now.
            self._gap_due = False
            self._gap_until = self.clock() + self.config.line_delay
        out = self.outgoing()
        if out:
            return Send(out, self.config.drain)
        if self.finished:
            return self._ending()
        wait = self.wait_time()
        gap = self._gap_until - self.clock()
        if gap > 0 and not self.streamer.paused:
            wait = max(0.001, min(wait, gap))
        if self.waiting is not None:
            self.waiting()
        return Wait(wait)

    def _ending(self) -> Step:
        """After the last byte: drain, then wait until the control's flow bytes stop."""
        now = self.clock()
        if self._done_at is None:
            self._done_at = now
            return Drain()
        if self._closed:
            return Finish()
        quiet = max(self._done_at, self._heard_at) + self.config.linger
        if self.config.xoff_timeout > 0:
            # a control that keeps pausing and resuming for this long has the whole program
            quiet = min(quiet, self._done_at + self.config.xoff_timeout)
        if now >= quiet:
            return Finish()
        return Wait(min(POLL, quiet - now))

    def wait_time(self) -> float:
        """Seconds a paused driver may wait for input; raises once XOFF lasted too long."""
        timer = self.streamer.timer
        if timer is None:
            return POLL
        now = self.clock()
        if timer.serial != self._timer_serial:
            self._timer_serial, self._deadline = timer.serial, now + timer.seconds
        if now >= self._deadline:
            self.streamer.timed_out()
        return max(0.001, min(POLL, self._deadline - now))

    def position(self) -> FeedPosition | None:
        """Where a run stopped before its end, exactly (:class:`FeedPosition`), or None where
        that is not known: a stop inside a write, the leader, the opening ``%`` or a restart's
        preamble, or a file with CR-only line ends."""
        if self.writing or self.feed.cr_split or self.finished:
            return None
        sent = self.streamer.sent
        whole = self._whole
        for mark in self._marks:
            if mark[0] > sent:
                break
            whole = mark
        if whole is None or whole[2] not in ("open", "line"):
            return None
        ended, offset, _kind = whole
        written = sent - ended
        if written:
            # the bytes of the next item the control has: from the stream handed out, which
            # the streamer no longer holds, so rebuilt from the program itself
            nxt = next((m for m in self._marks if m[0] > sent), None)
            if nxt is None or nxt[2] not in ("line", "close", "trailer"):
                return None
            item = self._item_at(offset, nxt[2])
            if item is None:
                return None
            return FeedPosition(offset, item[:written])
        return FeedPosition(offset)

    def _item_at(self, offset: int, kind: str) -> bytes | None:
        """The wire bytes of the item after ``offset`` (the next non-blank program line, the
        added closing ``%`` or the trailer), read again from the file."""
        if kind == "trailer":
            return self.config.trailer
        with self.feed.path.open("rb") as file:
            file.seek(offset)
            for raw in file:
                text = raw.rstrip(b"\r\n")
                if text.strip():
                    return (text if kind == "line" else b"%") + self.feed.eob.wire
        return b"%" + self.feed.eob.wire if kind == "close" else None

    def report(self) -> DncReport:
        """What the run did."""
        feed, streamer = self.feed, self.streamer
        if self.progress is not None:
            self.progress(feed.total, feed.total)
        return DncReport(
            path=feed.path,
            bytes_sent=streamer.sent,
            lines=feed.lines,
            xoffs=streamer.xoffs,
            xons=streamer.xons,
            paused_seconds=self._paused_total,
            seconds=self.clock() - self.started,
            restart=feed.plan,
        )
