"""XModem the way the virtual Haas speaks it, on the client's engines and blocking driver.

The engines (:mod:`opendnc.xmodem`) are standard; the Haas differences seen in the OpenDNC capture
(docs/xmodem.md#haas-dialect) are
each a knob of :class:`XmodemQuirks`, set on the engine where it has one:

* receiving, it answers the EOT of a complete transfer with CAN CAN CAN instead of ACK
  (the receiver's ``eot_answer`` setting);
* receiving, the control repeats its start request, and repeats come as several NAKs
  (capture: one NAK, then two NAKs about 2 s later) -- added at the byte boundary by
  :class:`QuirkStream`;
* punching, it may leave the PC's first NAK unanswered (capture: the transfer started on the
  second NAK, 10 s later) -- off by default, it only slows tests down; also in QuirkStream;
* punching, the text starts with an LF before ``%`` and has an empty block before the closing
  ``%`` (:func:`punch_bytes`); the last block is SUB padded by the engine.

In ``auto`` mode the receiver's ``text_start`` setting watches the first significant byte: an
XModem start byte continues the transfer, anything else (``%`` of a plain-text drip-feed)
ends it, and :func:`receive_xmodem` returns :class:`TextStart` so the caller can switch to DNC.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from opendnc.errors import DncError
from opendnc.transport.base import ByteStream
from opendnc.xmodem.driver import run_blocking
from opendnc.xmodem.events import Completed, DataReceived, EotAnswer, Event
from opendnc.xmodem.framing import CAN, EOT, NAK, SOH, STX, Mode
from opendnc.xmodem.haas import Eob, to_wire
from opendnc.xmodem.receiver import PlainTextStart, ReceiverConfig, XmodemReceiver
from opendnc.xmodem.sender import SenderConfig, XmodemSender

if TYPE_CHECKING:
    from opendnc.sim.haas.serial_front import SerialOptions

_XMODEM_START = frozenset((SOH, STX, EOT, CAN))


@dataclass(frozen=True, slots=True)
class XmodemQuirks:
    """Fidelity knobs for XModem on the virtual Haas."""

    extra_naks: int = 2  # NAKs added to every repeated start request
    can_after_eot: bool = True
    ignore_first_nak: bool = False
    leading_lf: bool = True
    nak_interval: float = 2.0  # seconds between start requests
    start_timeout: float = 3600.0  # how long the control waits for a sender / receiver


@dataclass(frozen=True, slots=True)
class TextStart:
    """``auto`` mode: the PC started sending plain text; ``text`` is what came so far."""

    text: bytes


class Interrupted(DncError):
    """The operator selected something else before the transfer started."""


def punch_bytes(text: str, eob: Eob) -> bytes:
    """A stored program as a Haas punches it: ``LF % LF O.. LF .. M30 LF LF % LF``."""
    body = text.replace("\r\n", "\n").strip("\n")
    if body.endswith("\n%"):
        body = body[: -len("\n%")] + "\n\n%"
    return to_wire(("\n" + body + "\n").encode("latin-1"), eob)


class QuirkStream:
    """A :class:`ByteStream` over the port that adds the Haas start-up quirks (module doc)."""

    def __init__(
        self,
        port: ByteStream,
        write: Callable[[bytes], None],
        quirks: XmodemQuirks,
        *,
        receiving: bool,
        interrupt: threading.Event | None = None,
        stop: threading.Event | None = None,
    ) -> None:
        self._interrupt = interrupt
        self._stop = stop
        self._port = port
        self._write = write
        self.quirks = quirks
        self.receiving = receiving
        self._requests = 0
        self._started = False
        self._nak_dropped = False

    def read(self, max_bytes: int) -> bytes:
        if self._interrupt is not None and self._interrupt.is_set() and not self._started:
            raise Interrupted("another serial mode was selected")
        if self._stop is not None and self._stop.is_set():
            raise Interrupted("the simulator is shutting down")
        data = self._port.read(max_bytes)
        if self.receiving and not self._started and not _XMODEM_START.isdisjoint(data):
            self._started = True
        if not self.receiving and data and not self._started:
            self._started = True
        if not self.receiving and self.quirks.ignore_first_nak and not self._nak_dropped:
            index = data.find(bytes((NAK,)))
            if index >= 0:
                self._nak_dropped = True
                data = data[:index] + data[index + 1 :]
        return data

    def write(self, data: bytes) -> None:
        if self.receiving and data == bytes((NAK,)) and not self._started:
            self._requests += 1
            if self._requests > 1:
                data = data * (1 + self.quirks.extra_naks)
        self._write(data)

    def set_timeout(self, seconds: float | None) -> None:
        self._port.set_timeout(seconds)

    def close(self) -> None:
        """The port belongs to the front-end."""

    def on_event(self, event: Event) -> None:
        """Watch the receiver: a block means the transfer runs."""
        if isinstance(event, DataReceived):
            self._started = True


def receive_xmodem(
    port: ByteStream,
    write: Callable[[bytes], None],
    options: SerialOptions,
    *,
    text_ok: bool = False,
    on_data: Callable[[bytes], None] | None = None,
    interrupt: threading.Event | None = None,
    stop: threading.Event | None = None,
) -> bytes | TextStart:
    """Receive one program as the control does; ``on_data`` sees each block's bytes in order.

    With ``text_ok`` a plain-text start returns :class:`TextStart` instead.
    """
    quirks = options.quirks
    stream = QuirkStream(port, write, quirks, receiving=True, interrupt=interrupt, stop=stop)
    config = ReceiverConfig(
        start_timeout=quirks.start_timeout,
        start_interval=quirks.nak_interval,
        crc_tries=0,  # Haas knows only the checksum variant
        eot_answer=EotAnswer.CAN if quirks.can_after_eot else EotAnswer.ACK,
        text_start=text_ok,
    )
    engine = XmodemReceiver(Mode.CHECKSUM, config)
    chunks: list[bytes] = []

    def handle(event: Event) -> None:
        stream.on_event(event)
        if isinstance(event, DataReceived):
            if on_data is not None:
                on_data(event.data)
            else:
                chunks.append(event.data)

    try:
        run_blocking(engine, stream, on_event=handle)
    except PlainTextStart as text:
        return TextStart(text.text)
    return b"".join(chunks)


def send_xmodem(
    port: ByteStream,
    write: Callable[[bytes], None],
    data: bytes,
    options: SerialOptions,
    interrupt: threading.Event | None = None,
    stop: threading.Event | None = None,
) -> Completed:
    """Punch ``data`` (see :func:`punch_bytes`) by XModem checksum, as the control does."""
    quirks = options.quirks
    stream = QuirkStream(port, write, quirks, receiving=False, interrupt=interrupt, stop=stop)
    config = SenderConfig(start_timeout=quirks.start_timeout)
    return run_blocking(XmodemSender(data, Mode.CHECKSUM, config), stream)
