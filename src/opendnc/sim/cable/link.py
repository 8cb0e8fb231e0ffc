"""The virtual null-modem cable: two pseudo-terminals joined at line speed, with line faults.

A pty moves bytes as fast as memory allows and ignores baud and parity, so the cable does the
timing itself. Each direction (a "lane") is a deadline schedule on ``time.monotonic()``: a byte
read from one master enters the line when the line is free, and is written to the other master
exactly ``bits_per_char / baud`` seconds later. Deadlines are computed from the start of a
chunk, never by adding up sleeps, so the average rate has no drift; waking up late only delays
a batch, it does not slow the line. Both lanes run independently (full duplex) in one
background thread that polls both masters.

Like a real port with nobody listening, a side whose slave is not open (the pty master reports
a hang-up) loses the bytes that arrive for it; the cable notices when the slave is opened again
and carries on.

Using the cable from Python (tests, benchmarks)::

    with VirtualCable(baud=115200, noise=1e-5, drop=1e-5, seed=7) as cable:
        sender = SerialStream(cable.path_a, 115200, timeout=0.05)
        receiver = SerialStream(cable.path_b, 115200, timeout=0.05)
        ...                         # open both ends before traffic starts
        cable.wait_idle()           # everything sent has been read
        print(cable.stats)          # a CableStats snapshot, live

``VirtualCable(..., monitor="line.txt")`` also logs every delivery with its time
(:mod:`opendnc.sim.cable.monitor`).

A payload-efficiency benchmark compares payload bytes per second with the line ceiling
``cable.bytes_per_second`` times the payload share of a block with its ACK (128/133 checksum,
128/134 CRC, 1024/1030 1K: 11,087, 11,004 and 11,453 B/s at 115200 8N1). In steady state,
measured from the line monitor (``monitor=``), our engines reach about 97.1 %, 97.2 % and
99.5 % of that and lrzsz 97.6 %, 97.7 % and 99.6 %; see ``benchmarks/xmodem.py``.
A byte of a busy line leaves at ``start + k * bits_per_char / baud``; a lone byte arrives one
character time plus about 0.1-0.2 ms of pump latency after it was written. Use
``bits_per_char=11`` for 8E1 or 8N2.

When the code under test is CPU-bound in the same interpreter (PyPI ``xmodem``'s pure-Python
CRC, for instance), the pump thread may wait for the GIL; run the cable in its own process with
:class:`~opendnc.sim.cable.process.CableProcess` (``opendnc sim cable``) instead.
"""

from __future__ import annotations

import contextlib
import errno
import os
import select
import sys
import termios
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType

from opendnc.errors import InputError, TransportError
from opendnc.sim.cable.monitor import LineMonitor
from opendnc.sim.cable.noise import LineNoise, UartInput, uart_input
from opendnc.transport.pty import open_pty

READ_CHUNK = 4096
LANE_CAPACITY = 4096  # bytes a lane holds before it stops reading: the UART's FIFO + tx buffer
BATCH_SECONDS = 0.001  # bytes due within this window go out in one write (fewer wake-ups)
HANGUP_RECHECK = 0.005  # how often a side without an open slave is looked at again
# termios lacks the constant; the value is the kernels' own (Linux, and the BSDs / macOS)
_EXTPROC: int = getattr(termios, "EXTPROC", 0o200000 if sys.platform.startswith("linux") else 0x800)


@dataclass(frozen=True, slots=True)
class LaneStats:
    """Counters of one direction."""

    carried: int = 0  # bytes that went over the line (including corrupted and dropped ones)
    delivered: int = 0  # bytes handed to the far side
    corrupted: int = 0  # delivered bytes with at least one flipped bit
    dropped: int = 0  # bytes the line lost (the drop rate)
    bit_flips: int = 0  # flipped bits in delivered bytes
    unheard: int = 0  # bytes that arrived while the far side had no slave open
    parity_failed: int = 0  # delivered characters that failed the parity check (parity_check)


@dataclass(frozen=True, slots=True)
class CableStats:
    """Counters of both directions; ``a_to_b`` is what side A sent to side B."""

    a_to_b: LaneStats = field(default_factory=LaneStats)
    b_to_a: LaneStats = field(default_factory=LaneStats)

    @property
    def carried(self) -> int:
        """Bytes carried in both directions."""
        return self.a_to_b.carried + self.b_to_a.carried

    @property
    def corrupted(self) -> int:
        """Corrupted bytes in both directions."""
        return self.a_to_b.corrupted + self.b_to_a.corrupted

    @property
    def dropped(self) -> int:
        """Dropped bytes in both directions."""
        return self.a_to_b.dropped + self.b_to_a.dropped

    @property
    def parity_failed(self) -> int:
        """Characters that failed the parity check, both directions."""
        return self.a_to_b.parity_failed + self.b_to_a.parity_failed


class _Side:
    """One pty of the cable: the master we pump, and whether a user has its slave open."""

    def __init__(self, name: str) -> None:
        pair = open_pty()
        self.name = name
        self.fd = pair.master_fd
        self.path = pair.slave_path
        # The slave stays raw after we close it (termios live with the pty, measured); closing
        # it lets the master report a hang-up whenever no user holds the slave.
        os.close(pair.slave_fd)
        os.set_blocking(self.fd, False)
        self.open = False  # a user holds the slave
        self.checked_at = 0.0
        self.extproc = False  # we set EXTPROC on the slave (see uart_input)

    def refresh(self, now: float) -> bool:
        """Look whether the slave is open now (the hang-up condition is level-triggered).

        Returns True when the master has data to read (possibly left by a user who has just
        closed the slave).
        """
        probe = select.poll()
        probe.register(self.fd, select.POLLIN)
        events = probe.poll(0)
        revents = events[0][1] if events else 0
        self.open = not revents & select.POLLHUP
        self.checked_at = now
        return bool(revents & select.POLLIN)

    def uart_input(self) -> UartInput:
        """How the user of this side asked for characters failing parity (its termios).

        A pty master reads and writes the slave's settings. For marking the cable must write
        ``FF 00 c`` itself, but the slave's line discipline would double that FF (PARMRK
        escapes every FF it is given): EXTPROC makes it pass input unprocessed, so the cable
        sets it while the user asks for marks, and does the FF doubling itself.
        """
        try:
            attrs = termios.tcgetattr(self.fd)
        except termios.error:
            return UartInput.RAW
        iflag, lflag = attrs[0], attrs[3]
        if not iflag & termios.INPCK:
            mode = UartInput.RAW
        elif iflag & termios.IGNPAR:
            mode = UartInput.DROP
        elif iflag & termios.PARMRK and _EXTPROC and not iflag & termios.IXON:
            mode = UartInput.MARK
        else:
            # INPCK alone; or PARMRK with IXON, which EXTPROC would switch off: the line
            # discipline doubles FF, and a bad character can only arrive as NUL.
            mode = UartInput.NUL
        want = mode is UartInput.MARK
        if want != bool(lflag & _EXTPROC) and (want or self.extproc):
            attrs[3] = lflag | _EXTPROC if want else lflag & ~_EXTPROC
            with contextlib.suppress(termios.error):
                termios.tcsetattr(self.fd, termios.TCSANOW, attrs)
                self.extproc = want
        return mode


class _Lane:
    """One direction: bytes waiting for the line, their deadlines, and bytes waiting for write."""

    def __init__(self, src: _Side, dst: _Side, char_time: float, noise: LineNoise) -> None:
        self.src, self.dst = src, dst
        self.direction = f"{src.name}>{dst.name}"
        self.monitor: LineMonitor | None = None
        self.char_time = char_time
        self.noise = noise
        self.chunks: deque[tuple[float, bytes]] = deque()  # (line start time, bytes)
        self.head_sent = 0  # bytes of chunks[0] already off the line
        self.queued = 0  # bytes on the line, not yet due
        self.line_free_at = 0.0
        self.outbuf = bytearray()  # due bytes the destination pty did not take yet
        self.stats = _Counters()

    def room(self) -> int:
        return LANE_CAPACITY - self.queued - len(self.outbuf)

    def accept(self, data: bytes, now: float) -> None:
        """Put bytes read from the source on the line."""
        start = max(self.line_free_at, now)
        self.chunks.append((start, data))
        self.line_free_at = start + len(data) * self.char_time
        self.queued += len(data)
        self.stats.carried += len(data)

    def next_wake(self) -> float | None:
        """When the pump should come back: a batch after the next byte, or the last byte."""
        if not self.chunks:
            return None
        start, _ = self.chunks[0]
        next_due = start + (self.head_sent + 1) * self.char_time
        return min(next_due + BATCH_SECONDS, self.line_free_at)

    def take_due(self, now: float) -> None:
        """Move bytes whose deadline has passed through the noise into ``outbuf``."""
        due = bytearray()
        while self.chunks:
            start, data = self.chunks[0]
            done = min(len(data), int((now - start) / self.char_time + 1e-9))
            if done <= self.head_sent:
                break
            due += data[self.head_sent : done]
            if done < len(data):
                self.head_sent = done
                break
            self.chunks.popleft()
            self.head_sent = 0
        if not due:
            return
        self.queued -= len(due)
        result = self.noise.apply(bytes(due))
        self.stats.corrupted += result.corrupted
        self.stats.dropped += result.dropped
        self.stats.bit_flips += result.bit_flips
        if self.monitor is not None and result.data:
            self.monitor.record(self.direction, now, result.data)
        if self.noise.parity_check:
            self.stats.parity_failed += len(result.parity_errors)
            mode = self.dst.uart_input()
            self.outbuf += uart_input(result.data, result.parity_errors, mode)
        else:
            self.outbuf += result.data

    def flush(self, now: float) -> None:
        """Write ``outbuf`` to the destination, or lose it if nobody listens there."""
        if not self.outbuf:
            return
        if not self.dst.open:
            self.dst.refresh(now)  # a user may have opened the slave since the last look
        if not self.dst.open:
            self.stats.unheard += len(self.outbuf)
            self.outbuf.clear()
            return
        try:
            written = os.write(self.dst.fd, self.outbuf)
        except BlockingIOError:
            return  # the reader is slow; POLLOUT tells us when to go on
        except OSError as exc:
            if exc.errno != errno.EIO:
                raise
            self.dst.open = False
            return
        self.stats.delivered += written
        del self.outbuf[:written]

    @property
    def idle(self) -> bool:
        return not self.chunks and not self.outbuf


@dataclass(slots=True)
class _Counters:
    carried: int = 0
    delivered: int = 0
    corrupted: int = 0
    dropped: int = 0
    bit_flips: int = 0
    unheard: int = 0
    parity_failed: int = 0

    def snapshot(self) -> LaneStats:
        return LaneStats(
            self.carried,
            self.delivered,
            self.corrupted,
            self.dropped,
            self.bit_flips,
            self.unheard,
            self.parity_failed,
        )


class VirtualCable:
    """Two pseudo-terminals joined like a null-modem cable at ``baud``.

    Open :attr:`path_a` and :attr:`path_b` like serial ports. ``noise`` is the bit-error rate
    per data bit, ``drop`` the probability that a byte is lost; ``seed`` makes both
    reproducible (each direction gets its own stream of faults derived from it). ``link_a`` and
    ``link_b`` create symlinks to the two devices, removed again by :meth:`close`.
    ``monitor`` names a file that gets a timestamped line for every delivery in either
    direction (:mod:`opendnc.sim.cable.monitor`). ``parity_check`` models the parity bit: a
    character failing the check reaches the far side as that side's port settings ask for
    (:func:`~opendnc.sim.cable.noise.uart_input`: as read, NUL, dropped, or marked ``FF 00 c``).
    Use it as a context manager, or call :meth:`start` and :meth:`close`.
    """

    def __init__(
        self,
        baud: int = 115200,
        bits_per_char: int = 10,
        noise: float = 0.0,
        drop: float = 0.0,
        seed: int | None = None,
        *,
        link_a: str | os.PathLike[str] | None = None,
        link_b: str | os.PathLike[str] | None = None,
        monitor: str | os.PathLike[str] | None = None,
        parity_check: bool = False,
    ) -> None:
        if baud <= 0:
            raise InputError(f"baud must be positive, got {baud}")
        if not 1 <= bits_per_char <= 64:
            raise InputError(f"bits per character must be 1..64, got {bits_per_char}")
        self.baud = baud
        self.bits_per_char = bits_per_char
        self.char_time = bits_per_char / baud
        self.seed = seed
        noise_ab = LineNoise(
            noise, drop, None if seed is None else f"{seed}:a>b", parity_check=parity_check
        )
        noise_ba = LineNoise(
            noise, drop, None if seed is None else f"{seed}:b>a", parity_check=parity_check
        )
        self._a = _Side("a")
        self._b = _Side("b")
        self._lanes = (
            _Lane(self._a, self._b, self.char_time, noise_ab),
            _Lane(self._b, self._a, self.char_time, noise_ba),
        )
        self._links: list[Path] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        self._thread: threading.Thread | None = None
        self.error: TransportError | None = None  # what killed the pump, if anything
        self._monitor: LineMonitor | None = None
        try:
            for target, link in ((self._a.path, link_a), (self._b.path, link_b)):
                if link is not None:
                    self._make_link(Path(link), target)
            if monitor is not None:
                self._monitor = LineMonitor(monitor, time.monotonic())
                for lane in self._lanes:
                    lane.monitor = self._monitor
        except BaseException:
            self._close_fds()
            raise

    @property
    def path_a(self) -> str:
        """Device path of side A (open it like a serial port)."""
        return self._a.path

    @property
    def path_b(self) -> str:
        """Device path of side B."""
        return self._b.path

    @property
    def bytes_per_second(self) -> float:
        """The line rate of each direction: ``baud / bits_per_char``."""
        return self.baud / self.bits_per_char

    @property
    def stats(self) -> CableStats:
        """A consistent snapshot of the counters of both directions."""
        with self._lock:
            ab, ba = self._lanes
            return CableStats(ab.stats.snapshot(), ba.stats.snapshot())

    @property
    def monitor_error(self) -> InputError | None:
        """Why the line monitor stopped writing (a full disk, say); None while it works."""
        return None if self._monitor is None else self._monitor.error

    @property
    def running(self) -> bool:
        """True while the pump thread runs."""
        return self._thread is not None and self._thread.is_alive()

    def start(self) -> VirtualCable:
        """Start pumping in a background thread."""
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name="opendnc-cable", daemon=True)
            self._thread.start()
        return self

    def wait_idle(self, timeout: float = 5.0) -> bool:
        """Wait until no byte is unread, on the line or waiting for a reader; False on timeout.

        "Waiting for a reader" means the far side has not read what it was sent: call this
        while the receiving side keeps reading, or after it read everything.
        """
        deadline = time.monotonic() + timeout
        probe = select.poll()
        for side in (self._a, self._b):
            probe.register(side.fd, select.POLLIN)
        while time.monotonic() < deadline:
            with self._lock:
                lanes_idle = all(lane.idle for lane in self._lanes)
            # bytes a user wrote that the pump has not read yet sit in the master
            if lanes_idle and not any(ev & select.POLLIN for _, ev in probe.poll(0)):
                return True
            time.sleep(0.002)
        return False

    def close(self) -> None:
        """Stop the pump, hang up both ptys and remove the symlinks. Safe to call twice."""
        self._stop.set()
        with contextlib.suppress(OSError):
            os.write(self._wake_w, b"x")
        if self._thread is not None:
            self._thread.join(timeout=5)
        self._close_fds()

    def __enter__(self) -> VirtualCable:
        return self.start()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    # -- internals -------------------------------------------------------------------------

    def _make_link(self, link: Path, target: str) -> None:
        if link.is_symlink():
            link.unlink()  # left over from a cable that was killed hard
        elif link.exists():
            raise InputError(f"{link} exists and is not a symlink; not replacing it")
        try:
            link.symlink_to(target)
        except OSError as exc:
            raise InputError(f"cannot create symlink {link}: {exc}") from exc
        self._links.append(link)

    def _close_fds(self) -> None:
        if self._monitor is not None:
            with self._lock:  # not while a pump that outlived close() writes a record
                self._monitor.close()
        for link in self._links:
            with contextlib.suppress(OSError):
                link.unlink()
        self._links.clear()
        for fd in (self._a.fd, self._b.fd, self._wake_r, self._wake_w):
            with contextlib.suppress(OSError):
                os.close(fd)
        self._a.fd = self._b.fd = self._wake_r = self._wake_w = -1

    def _run(self) -> None:
        try:
            self._pump()
        except OSError as exc:
            # users of the ports see a silent line; `running` and `error` say why
            self.error = TransportError(f"virtual cable stopped: {exc}")

    def _pump(self) -> None:
        poller = select.poll()
        poller.register(self._wake_r, select.POLLIN)
        sides = (self._a, self._b)
        for side in sides:
            side.refresh(time.monotonic())
        registered: dict[int, int] = {}
        while not self._stop.is_set():
            now = time.monotonic()
            wake: float | None = None
            for side, out_lane, in_lane in (
                (self._a, self._lanes[0], self._lanes[1]),
                (self._b, self._lanes[1], self._lanes[0]),
            ):
                recheck_due = not side.open and now - side.checked_at >= HANGUP_RECHECK
                if recheck_due and side.refresh(now):
                    with self._lock:
                        self._read_side(side, out_lane, now)
                events = 0
                if side.open:
                    if out_lane.room() > 0:
                        events |= select.POLLIN
                    if in_lane.outbuf:
                        events |= select.POLLOUT
                else:
                    # a hung-up master polls as ready forever: look again in a moment instead
                    recheck = side.checked_at + HANGUP_RECHECK
                    wake = recheck if wake is None else min(wake, recheck)
                if side.open and events:
                    if registered.get(side.fd) != events:
                        poller.register(side.fd, events)
                        registered[side.fd] = events
                elif side.fd in registered:
                    poller.unregister(side.fd)
                    del registered[side.fd]
            for lane in self._lanes:
                lane_wake = lane.next_wake()
                if lane_wake is not None:
                    wake = lane_wake if wake is None else min(wake, lane_wake)
            ready = self._wait(poller, wake)
            now = time.monotonic()
            with self._lock:
                for fd, revents in ready:
                    if fd == self._wake_r:
                        with contextlib.suppress(BlockingIOError):
                            os.read(self._wake_r, 64)
                        continue
                    side = self._a if fd == self._a.fd else self._b
                    lane = self._lanes[0] if side is self._a else self._lanes[1]
                    if revents & select.POLLIN:
                        self._read_side(side, lane, now)
                    elif revents & (select.POLLHUP | select.POLLERR):
                        # hung up with nothing left to read (or no room to read it yet: the
                        # recheck of a closed side picks that up later)
                        side.open = False
                        side.checked_at = now
                for lane in self._lanes:
                    lane.take_due(now)
                    lane.flush(now)
                if self._monitor is not None and all(lane.idle for lane in self._lanes):
                    self._monitor.flush(now)

    def _wait(self, poller: select.poll, wake: float | None) -> list[tuple[int, int]]:
        if wake is None:
            return poller.poll(None)
        remaining = wake - time.monotonic()
        if remaining <= 0:
            return poller.poll(0)
        # poll() counts whole milliseconds: poll for the whole part, sleep the rest
        ready = poller.poll(int(remaining * 1000))
        if not ready:
            rest = wake - time.monotonic()
            if rest > 0:
                time.sleep(rest)
        return ready

    def _read_side(self, side: _Side, lane: _Lane, now: float) -> None:
        room = lane.room()
        if room <= 0:
            return
        try:
            data = os.read(side.fd, min(room, READ_CHUNK))
        except BlockingIOError:
            return
        except OSError as exc:
            if exc.errno != errno.EIO:
                raise
            # EIO: the last user closed the slave (whatever it wrote before was read already)
            side.open = False
            side.checked_at = now
            return
        if data:
            lane.accept(data, now)
