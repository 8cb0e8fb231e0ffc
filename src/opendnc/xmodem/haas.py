"""Haas program conventions on an XModem link.

A Haas punches a program as ``LF % LF O05555(comment) LF ... M30 LF LF % LF`` and pads the
last block with SUB (docs/xmodem.md#haas-captures, Figure 23). The end-of-block bytes follow setting
25 (EOB
pattern): LF, CR, CR LF, CR CR or LF LF. On the PC side programs are kept with LF line ends;
:func:`to_wire` and :func:`from_wire` convert in between. ``%`` delimiters, the O-number line
and every other byte are left exactly as they are.
"""

from __future__ import annotations

import enum
import re
from dataclasses import dataclass

from opendnc.xmodem.framing import SUB


class Eob(enum.Enum):
    """Setting 25 (EOB pattern) choices, named as on the command line."""

    LF = "lf"
    CR = "cr"
    CRLF = "crlf"
    CRCR = "crcr"
    LFLF = "lflf"

    @property
    def wire(self) -> bytes:
        """The bytes that end a block on the wire."""
        return _WIRE[self]


_WIRE = {
    Eob.LF: b"\n",
    Eob.CR: b"\r",
    Eob.CRLF: b"\r\n",
    Eob.CRCR: b"\r\r",
    Eob.LFLF: b"\n\n",
}

_ANY_LINE_END = re.compile(rb"\r\n|\r|\n")


def to_wire(program: bytes, eob: Eob = Eob.LF) -> bytes:
    """Convert a program's line ends (LF, CR LF or CR, mixed) to the control's EOB bytes."""
    if eob is Eob.LF and b"\r" not in program:
        return program
    wire = eob.wire
    return _ANY_LINE_END.sub(lambda _match: wire, program)


def from_wire(data: bytes, eob: Eob = Eob.LF) -> bytes:
    """Convert the control's EOB bytes to LF line ends.

    With CR LF and CR the conversion is tolerant: any CR LF, lone CR or LF becomes one LF.
    With the doubled patterns (CR CR, LF LF) each pair becomes one LF, and a leftover single
    byte is also taken as an end of block.
    """
    if eob is Eob.LF:
        return data
    if eob in (Eob.CR, Eob.CRLF):
        return _ANY_LINE_END.sub(b"\n", data)
    pair = eob.wire
    single = pair[:1]
    return re.sub(re.escape(pair) + b"|" + re.escape(single), b"\n", data)


def strip_padding(data: bytes) -> bytes:
    """Remove the trailing SUB (0x1A) padding of an XModem file."""
    return data.rstrip(bytes((SUB,)))


_O_NUMBER = re.compile(rb"^[ \t]*O(\d{1,5})[ \t]*(?:\(([^)\r\n]*)\))?", re.MULTILINE)


@dataclass(frozen=True, slots=True)
class ProgramHeader:
    """The O-number line of a program: ``O05555(CS390_Test_NC)``."""

    number: int
    name: str  # as written, e.g. "O05555"
    comment: str | None


def program_header(data: bytes) -> ProgramHeader | None:
    """Find the program's O-number in its first non-empty line after the opening ``%``.

    Returns ``None`` when the program carries no O-number there.
    """
    for raw in _ANY_LINE_END.split(data[:4096]):
        line = raw.strip(b" \t\x00")
        if not line or line == b"%":
            continue
        match = _O_NUMBER.match(line)
        if match is None:
            return None
        comment = match.group(2)
        return ProgramHeader(
            number=int(match.group(1)),
            name="O" + match.group(1).decode("ascii"),
            comment=comment.decode("latin-1") if comment is not None else None,
        )
    return None


def program_filename(data: bytes, default: str = "program.nc") -> str:
    """A file name for a received program: ``O05555.nc`` from its O-number, else ``default``."""
    header = program_header(data)
    return f"{header.name}.nc" if header is not None else default


def has_tape_delimiters(data: bytes) -> bool:
    """True when the program starts and ends with a ``%`` line (leading/trailing EOBs allowed)."""
    lines = [line.strip(b" \t\x00") for line in _ANY_LINE_END.split(strip_padding(data))]
    content = [line for line in lines if line]
    return len(content) >= 2 and content[0] == b"%" and content[-1] == b"%"
