"""LSV2 over an RS-232 line: the serial link engine run over a real port (docs/lsv2-serial.md).

:class:`SerialLsv2Stream` is a byte stream like a TCP socket to the control: the LSV2 engine
(:class:`~opendnc.lsv2.connection.Lsv2Connection`) writes TCP-framed telegrams into it and
reads TCP-framed answers back, while underneath each telegram travels as one serial
transmission (ENQ, DLE 0, frame, DLE 1, EOT) driven by
:class:`~opendnc.lsv2.serial_link.SerialLink`.
So the operations of :mod:`opendnc.lsv2.ops` and both clients run unchanged; only the link
under them differs.

:class:`SerialLine` holds the port settings; :func:`open_line` is the one place where a port,
``socket://`` serial server or ``rfc2217://`` URL is opened (through
:func:`opendnc.transport.serial.open_stream`).
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import get_args

from opendnc.errors import InputError, TransportError, TransportTimeout
from opendnc.lsv2.framing import Frame, TelegramFramer
from opendnc.lsv2.ops.base import TelegramSizer
from opendnc.lsv2.serial_link import (
    DEFAULT_TIMING,
    CharHook,
    HostStatus,
    LinkChecked,
    LinkFailed,
    LinkRole,
    LinkStats,
    LinkTiming,
    SerialLink,
    SerialLinkError,
    TelegramReceived,
    TelegramSent,
)
from opendnc.transport.base import ByteStream
from opendnc.transport.line import Handshake
from opendnc.transport.marks import LineData, line_reader

__all__ = [
    "BAUD_PROBE_ORDER",
    "FLOW_CONTROLS",
    "AsyncSerialLink",
    "SerialLine",
    "SerialLsv2Stream",
    "open_line",
    "open_lsv2_serial",
    "probe_baud",
]

DEFAULT_BAUD = 57600
BAUD_PROBE_ORDER: tuple[int, ...] = (57600, 115200, 38400, 19200, 9600, 4800, 2400)
"""Rates tried by ``--baud auto``, most likely first (57600 is the controls' default)."""
FLOW_CONTROLS = get_args(Handshake)  # what the port dispatcher takes
POLL = 0.02
"""Seconds one read of the port waits before the engine's clock is looked at again."""
_NOTHING = LineData(b"")


@dataclass(frozen=True, slots=True)
class SerialLine:
    """How to reach a control over RS-232 (defaults: 57600 baud 8E1, no flow control)."""

    url: str
    """A device (``/dev/ttyUSB0``, ``COM3``), ``socket://host:port`` or ``rfc2217://host:port``."""
    baud: int | None = DEFAULT_BAUD
    """Line rate; ``None`` probes :data:`BAUD_PROBE_ORDER` with ENQ (``--baud auto``)."""
    parity: str = "E"
    bytesize: int = 8
    stopbits: float = 1
    flow: str = "none"
    timing: LinkTiming = field(default=DEFAULT_TIMING)
    retries: int = 3
    nak_retries: int = 12
    """Repeats of a telegram the control refuses with NAK (a live but noisy line): at a
    bit-error rate of 1e-4 a 256-byte telegram fails about one try in five, so three repeats
    lost a block in 600 (docs/lsv2-serial.md, "Telegram size")."""
    link_check: bool = True
    """Send the lone ENQ before the first telegram, as TNCremo does."""
    mark_errors: bool = True
    """Have the port mark characters that fail their parity or framing check, so that such a
    character spoils its block (POSIX devices; docs/lsv2-serial.md, "Parity errors")."""
    telegram_size: int | None = None
    """Telegram size to ask for (bytes, 64-4096; caps the negotiated buffer, which starts at
    256 and can only grow); ``None`` leaves it to the client's ``max_buffer``. Uploads adapt
    below it to the line (docs/lsv2-serial.md, "Telegram size")."""

    def __post_init__(self) -> None:
        if self.flow not in FLOW_CONTROLS:
            raise InputError(f"unknown flow control {self.flow!r}: use {', '.join(FLOW_CONTROLS)}")
        if self.parity.upper() not in ("N", "E", "O"):
            raise InputError(f"unknown parity {self.parity!r}: use N, E or O")
        if self.bytesize not in (7, 8):
            raise InputError(f"LSV2 needs 7 or 8 data bits, got {self.bytesize}")
        if self.stopbits not in (1, 1.5, 2):
            raise InputError(f"stop bits must be 1, 1.5 or 2, got {self.stopbits:g}")
        if self.baud is not None and self.baud <= 0:
            raise InputError(f"bad baud rate {self.baud}")
        if self.telegram_size is not None and not 64 <= self.telegram_size <= 4096:
            raise InputError(f"telegram size must be 64-4096 bytes, got {self.telegram_size}")

    @property
    def bits_per_char(self) -> int:
        """Line bits per character: start + data + parity + stop (8E1 = 11)."""
        parity = 0 if self.parity.upper() == "N" else 1
        return int(1 + self.bytesize + parity + self.stopbits + 0.5)

    def describe(self) -> str:
        """E.g. ``/dev/ttyUSB0 57600 8E1``."""
        baud = "auto" if self.baud is None else str(self.baud)
        flow = "" if self.flow == "none" else f" {self.flow}"
        return f"{self.url} {baud} {self.bytesize}{self.parity.upper()}{self.stopbits:g}{flow}"


def line_parity(url: str, parity: str) -> str:
    """The parity to ask the OS for: ``N`` on a pseudo-terminal, else ``parity``.

    A pty carries no parity bits at all, and some kernels refuse to switch parity on one
    (``tcsetattr`` fails with EINVAL on the second open); the virtual cable accounts for the
    parity bit in its timing instead (``--bits-per-char 11``).
    """
    if "://" not in url:
        with contextlib.suppress(OSError):
            if os.path.realpath(url).startswith("/dev/pts/"):
                return "N"
    return parity.upper()


def open_line(line: SerialLine, baud: int | None = None) -> ByteStream:
    """Open the port of ``line`` (at ``baud`` if given) as a raw byte stream."""
    from opendnc.transport import open_stream

    rate = baud or line.baud or DEFAULT_BAUD
    return open_stream(
        line.url,
        rate,
        timeout=POLL,
        parity=line_parity(line.url, line.parity),
        bytesize=line.bytesize,
        stopbits=line.stopbits,
        flow="rtscts" if line.flow == "rtscts" else "xonxoff" if line.flow == "xonxoff" else "none",
        mark_errors=line.mark_errors,
    )


def probe_baud(
    line: SerialLine, rates: Sequence[int] = BAUD_PROBE_ORDER, *, wait: float = 0.5
) -> int:
    """Find the rate at which the control answers ENQ with DLE 0 (then released with EOT)."""
    for rate in rates:
        stream = open_line(line, rate)
        try:
            link = SerialLink(LinkRole.CLIENT, timing=LinkTiming(time1=min(wait, 3.6)), retries=0)
            driver = _Pump(stream, link)
            link.check_link(time.monotonic())
            try:
                driver.until_checked()
            except SerialLinkError:
                continue
            driver.flush()  # the EOT that releases the control
            return rate
        finally:
            stream.close()
    tried = ", ".join(str(r) for r in rates)
    raise SerialLinkError(HostStatus.NO_ENQ, f"no answer to ENQ on {line.url} at {tried} baud")


class _Pump:
    """Runs a :class:`SerialLink` over a blocking byte stream with the monotonic clock."""

    def __init__(
        self, stream: ByteStream, link: SerialLink, sizer: TelegramSizer | None = None
    ) -> None:
        self.stream = stream
        self.link = link
        self.sizer = sizer
        self.inbox: list[Frame] = []
        self.checked = False
        self.spoken = False
        self.drop_before_first = True
        self.stale = 0
        stream.set_timeout(POLL)
        self._read = line_reader(stream)

    def flush(self) -> None:
        out = self.link.data_to_send()
        if out:
            self.stream.write(out)

    def until_checked(self) -> None:
        """Pump until the link check was answered."""
        self.until(lambda: self.checked, None)

    def until(self, done: Callable[[], bool], idle_deadline: float | None) -> None:
        """Pump until ``done`` holds; ``idle_deadline`` bounds waits while the line is idle."""
        link = self.link
        naks = link.stats.naks_sent
        heard = time.monotonic()
        # The control gives a telegram up silently once its retries are spent: we refused it
        # (NAK) and nothing more comes. Its retry would follow within its LSV2TIME1.
        gave_up = link.timing.time1 + link.timing.time2 + 0.5
        while True:
            self.flush()
            while (event := link.next_event()) is not None:
                if isinstance(event, TelegramReceived):
                    if self.spoken or not self.drop_before_first:
                        self.inbox.append(event.frame)
                    else:
                        # The control speaks only after a request: a telegram before our
                        # first one was acknowledged is a late answer to the previous client
                        # on this line (its last DLE 1 got lost), not ours.
                        self.stale += 1
                elif isinstance(event, TelegramSent):
                    self.spoken = True
                    if self.sizer is not None and event.frame.mnemonic == "S_FL":
                        self.sizer.block_sent(event.tries)
                elif isinstance(event, LinkChecked):
                    self.checked = True
                elif isinstance(event, LinkFailed):
                    raise event.error
            if done():
                return
            now = time.monotonic()
            if link.deadline is None and idle_deadline is not None:
                refused = link.stats.naks_sent - naks
                if refused and now - heard >= gave_up:
                    raise SerialLinkError(
                        HostStatus.TX_ERROR,
                        f"the control's telegram refused {refused} times here, then given up "
                        "(its retries spent)",
                    )
                if now >= idle_deadline:
                    raise TransportTimeout("no answer from the control over the serial line")
            try:
                got = self._read(4096)
            except TransportTimeout:
                got = _NOTHING
            now = time.monotonic()
            if got.data:
                heard = now
            link.receive_data(got.data, now, got.errors)
            link.tick(now)


class SerialLsv2Stream:
    """A byte stream of TCP-framed LSV2 telegrams carried over a serial line (client end)."""

    def __init__(
        self,
        line: ByteStream,
        *,
        timing: LinkTiming = DEFAULT_TIMING,
        retries: int = 3,
        link_check: bool = True,
        on_link: CharHook | None = None,
        description: str = "serial line",
        telegram_size: int | None = None,
        nak_retries: int | None = None,
    ) -> None:
        self.line = line
        self.description = description
        self.link = SerialLink(
            LinkRole.CLIENT,
            timing=timing,
            retries=retries,
            on_bytes=on_link,
            nak_retries=nak_retries,
        )
        self.sizer = TelegramSizer(ceiling=telegram_size or 4096)
        """Upload telegram size, fed by the tries each block needed (docs/lsv2-serial.md)."""
        self._pump = _Pump(line, self.link, self.sizer)
        self._framer = TelegramFramer()
        self._timeout: float | None = 10.0
        self._closed = False
        if link_check:
            self.link.check_link(time.monotonic())  # sent together with the first telegram

    @property
    def stats(self) -> LinkStats:
        """Counters of the link engine (:class:`~opendnc.lsv2.serial_link.LinkStats`)."""
        return self.link.stats

    def write(self, data: bytes) -> None:
        """Send the TCP-framed telegrams in ``data``, each as one serial transmission."""
        self._framer.feed(data)
        now = time.monotonic()
        while (frame := self._framer.next_frame()) is not None:
            self.link.send(frame, now)
        try:
            self._pump.until(lambda: not self.link.busy_sending, None)
        except TransportError:
            self.link.abandon(time.monotonic())
            self._pump.flush()
            raise

    def read(self, max_bytes: int) -> bytes:
        """Return the next telegram from the control, TCP-framed."""
        pump = self._pump
        if not pump.inbox:
            deadline = None if self._timeout is None else time.monotonic() + self._timeout
            pump.until(lambda: bool(pump.inbox), deadline)
        frame = pump.inbox.pop(0)
        return TelegramFramer.encode(frame)

    def set_timeout(self, seconds: float | None) -> None:
        """How long :meth:`read` waits for the control to start its answer."""
        self._timeout = seconds

    def close(self) -> None:
        """Release the line (an idle link needs no goodbye)."""
        if not self._closed:
            self._closed = True
            self.line.close()


def open_lsv2_serial(line: SerialLine, *, on_link: CharHook | None = None) -> SerialLsv2Stream:
    """Open ``line`` (probing the baud rate if it is ``None``) for an LSV2 client."""
    if line.baud is None:
        line = replace(line, baud=probe_baud(line))
    stream = open_line(line)
    return SerialLsv2Stream(
        stream,
        timing=line.timing,
        retries=line.retries,
        link_check=line.link_check,
        on_link=on_link,
        description=line.describe(),
        telegram_size=line.telegram_size,
        nak_retries=line.nak_retries,
    )


class AsyncSerialLink:
    """The asyncio face of :class:`SerialLsv2Stream` (``AsyncDriver`` link).

    A serial port has no portable asyncio transport, so the blocking stream runs in a worker
    thread, one call at a time; the link engine and everything above it are the same.
    """

    def __init__(self, stream: SerialLsv2Stream) -> None:
        self.stream = stream

    @classmethod
    async def open(cls, line: SerialLine, *, on_link: CharHook | None = None) -> AsyncSerialLink:
        """Open ``line`` in a worker thread."""
        return cls(await asyncio.to_thread(open_lsv2_serial, line, on_link=on_link))

    async def write(self, data: bytes) -> None:
        """Send TCP-framed telegrams (one serial transmission each)."""
        await asyncio.to_thread(self.stream.write, data)

    async def read(self, timeout: float) -> bytes:
        """Next telegram from the control, TCP-framed."""

        def call() -> bytes:
            self.stream.set_timeout(timeout)
            return self.stream.read(65536)

        return await asyncio.to_thread(call)

    async def close(self) -> None:
        """Release the port."""
        self.stream.close()
