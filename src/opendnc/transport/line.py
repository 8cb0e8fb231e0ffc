"""Serial line settings as opendnc spells them, checked before any port is touched."""

from __future__ import annotations

from typing import Literal

from opendnc.errors import InputError

Handshake = Literal["none", "rtscts", "xonxoff"]
"""Flow control done by the port (driver or UART): none, hardware RTS/CTS, or XON/XOFF."""

HANDSHAKES: tuple[Handshake, ...] = ("none", "rtscts", "xonxoff")
PARITIES = ("N", "E", "O", "M", "S")  # none, even, odd, mark, space (pyserial's PARITY_*)
BYTESIZES = (5, 6, 7, 8)
STOPBITS = (1, 1.5, 2)


def check_line(parity: str, bytesize: int, stopbits: float, flow: str) -> None:
    """Raise :class:`InputError` for line settings no serial port has."""
    if parity.upper() not in PARITIES:
        raise InputError(f"unknown parity {parity!r}: use N, E, O, M or S")
    if bytesize not in BYTESIZES:
        raise InputError(f"bad byte size {bytesize}: use 5, 6, 7 or 8")
    if stopbits not in STOPBITS:
        raise InputError(f"bad stop bits {stopbits:g}: use 1, 1.5 or 2")
    if flow not in HANDSHAKES:
        raise InputError(f"unknown flow control {flow!r}: use none, rtscts or xonxoff")
