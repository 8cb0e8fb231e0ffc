"""Characters that failed their parity (or framing) check, as a POSIX serial port marks them.

A UART that finds a bad parity bit still hands the character over. What the reader gets
depends on the port's input flags (docs/lsv2-serial.md, "Parity errors"): with ``INPCK`` and
``PARMRK`` set (and ``IGNPAR`` and ``ISTRIP`` clear) Linux and the BSDs deliver a bad
character ``c`` as the three bytes ``FF 00 c`` and a good 0xFF as ``FF FF``; a break arrives
as ``FF 00 00``. :class:`MarkDecoder` turns that form back into the bytes that were sent plus
the positions of the characters that cannot be trusted, so a protocol can refuse the block
that holds one instead of letting two bad characters cancel in an XOR check.

:func:`enable_marks` switches a pyserial port on POSIX to that form. Where a port cannot mark
(Windows, ``socket://``, ``rfc2217://``) the reader gets plain bytes and
:func:`read_line_data` reports no errors.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

__all__ = ["LineData", "MarkDecoder", "enable_marks", "line_reader"]

_FF = 0xFF


@dataclass(frozen=True, slots=True)
class LineData:
    """Bytes read from a line; ``errors`` are indices into ``data`` of characters that arrived
    with a parity or framing error (their value there is what the UART read, unreliable)."""

    data: bytes
    errors: tuple[int, ...] = ()


class MarkDecoder:
    """Undoes ``PARMRK`` marking, chunk by chunk (a mark may be split across two reads)."""

    def __init__(self) -> None:
        self._held = b""  # FF or FF 00 at the end of the last chunk
        self.marked = 0
        """Characters reported with an error so far."""

    def decode(self, raw: bytes) -> LineData:
        """Decode one chunk read from a marking port."""
        if self._held:
            raw = self._held + raw
            self._held = b""
        if _FF not in raw:
            return LineData(bytes(raw))
        out = bytearray()
        errors: list[int] = []
        i = 0
        n = len(raw)
        while i < n:
            j = raw.find(_FF, i)
            if j < 0:
                out += raw[i:]
                break
            out += raw[i:j]
            if j + 1 >= n or (raw[j + 1] == 0 and j + 2 >= n):
                self._held = bytes(raw[j:])  # the rest of the mark comes with the next read
                break
            nxt = raw[j + 1]
            if nxt == _FF:
                out.append(_FF)  # an escaped data byte 0xFF
                i = j + 2
            elif nxt == 0:
                errors.append(len(out))  # FF 00 c: c failed its check (c = 0: a break)
                out.append(raw[j + 2])
                i = j + 3
            else:
                # Not a form the kernel produces (marking was switched on mid-stream): keep
                # the byte as data rather than lose it.
                out.append(_FF)
                i = j + 1
        self.marked += len(errors)
        return LineData(bytes(out), tuple(errors))


def enable_marks(port: Any) -> bool:
    """Make the POSIX serial port ``port`` (pyserial) mark bad characters; False if it cannot.

    pyserial clears ``PARMRK`` and ``INPCK`` whenever it applies its settings (on every change
    of baud rate or timeout), so the flags are set again after each of those.
    """
    fd = getattr(port, "fd", None)
    if not isinstance(fd, int) or sys.platform == "win32":
        return False  # Windows, socket://, rfc2217://: no termios under the port
    try:
        import termios
    except ImportError:  # pragma: no cover - POSIX always has termios
        return False

    def apply() -> None:
        attrs = termios.tcgetattr(fd)
        attrs[0] |= termios.INPCK | termios.PARMRK
        attrs[0] &= ~(termios.IGNPAR | termios.ISTRIP)
        termios.tcsetattr(fd, termios.TCSANOW, attrs)

    try:
        apply()
    except termios.error:
        return False
    reconfigure = port._reconfigure_port

    def reconfigure_and_mark(*args: Any, **kwargs: Any) -> None:
        reconfigure(*args, **kwargs)
        apply()

    port._reconfigure_port = reconfigure_and_mark
    return True


def line_reader(stream: Any) -> Callable[[int], LineData]:
    """``read(max_bytes)`` of ``stream`` returning :class:`LineData`: with error positions
    where the stream marks them (:class:`~opendnc.transport.serial.SerialStream`), none
    elsewhere."""
    read_marked = getattr(stream, "read_marked", None)
    if callable(read_marked):
        return read_marked  # type: ignore[no-any-return]
    read = stream.read
    return lambda max_bytes: LineData(read(max_bytes))
