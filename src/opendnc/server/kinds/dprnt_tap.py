"""DPRNT lines picked off a serial Haas's port while the server owns it for XModem and MDC.

A classic Haas prints DPRNT to its only serial port, the one the server listens on for punches
and asks Q-commands on. :class:`TapStream` sits between the port and those protocols and hands
the bytes that are neither to a :class:`DprntTap`:

* while the connector listens for a punch, everything up to an XModem start byte (SOH, EOT,
  CAN) is text the control printed; from that byte on the bytes are a program, not DPRNT;
* while it asks Q-commands, the replies are framed by STX/ETB and are dropped, the unframed
  lines between them are DPRNT (docs/haas.md#dprnt-over-serial);
* while it sends a program nothing is tapped (the control is receiving, not running).

Line noise (NUL, XON/XOFF, DC2/DC4 of POPEN/PCLOS, NAK, CAN, SUB) is dropped first.
"""

from __future__ import annotations

from collections.abc import Callable
from datetime import UTC, datetime

from opendnc.haas.dprnt import DprntLineFramer, FramedLine, parse_line
from opendnc.haas.listen import CapturedLine
from opendnc.haas.mdc import LINE_NOISE
from opendnc.server.kinds.connector import StreamWrapper
from opendnc.transport.base import ByteStream

__all__ = ["DprntTap", "TapStream"]

_XMODEM_START = (0x01, 0x04, 0x18)  # SOH, EOT, CAN
_MDC_FRAMING = ("\x02", "\x17")  # STX, ETB


class DprntTap:
    """Cuts tapped bytes into lines and hands each DPRNT line to ``on_line``."""

    def __init__(
        self,
        on_line: Callable[[CapturedLine], None],
        *,
        now: Callable[[], datetime] = lambda: datetime.now(UTC),
    ) -> None:
        self.on_line = on_line
        self.now = now
        self.lines = 0
        self._framer = DprntLineFramer()
        self._after_reply = False

    def feed(self, data: bytes) -> None:
        """Take printed bytes (MDC replies may be among them; they are dropped)."""
        # STX/ETB stay in: they tell a reply from a printed line
        self._framer.feed(data.translate(None, LINE_NOISE))
        for event in self._framer.events():
            if isinstance(event, FramedLine):
                self._line(event.text)

    def _line(self, text: str) -> None:
        if any(mark in text for mark in _MDC_FRAMING):
            self._after_reply = True  # its ">" prompt starts the next line
            return
        if self._after_reply:
            text = text.removeprefix(">")
            self._after_reply = False
        if not text.strip():
            return
        self.lines += 1
        self.on_line(CapturedLine(self.now(), text, parse_line(text).fields))


class TapStream(StreamWrapper):
    """A :class:`ByteStream` that shows what it reads to a :class:`DprntTap` when told to.

    ``mode`` is ``"off"``, ``"listen"`` (until an XModem start byte) or ``"mdc"``.
    """

    def __init__(self, inner: ByteStream, tap: DprntTap) -> None:
        super().__init__(inner)
        self.tap = tap
        self.mode = "off"

    def read(self, max_bytes: int) -> bytes:
        """Read from the port; tapped bytes go to the tap as well."""
        data = self.inner.read(max_bytes)
        if self.mode == "mdc":
            self.tap.feed(data)
        elif self.mode == "listen":
            starts = [i for i, byte in enumerate(data) if byte in _XMODEM_START]
            if starts:
                self.tap.feed(data[: starts[0]])
                self.mode = "off"  # a transfer started: the rest is a program
            else:
                self.tap.feed(data)
        return data
