"""The two punched-tape codes an NC control reads over RS-232: ISO and EIA RS-244.

* **ISO** (ISO 840 / ASCII): 7-bit characters. On an 8-bit tape or line the eighth channel
  carries **even** parity; :class:`Codec` with ``parity=True`` sets and checks it (a 7E2 line
  and an 8N2 line with the parity bit in the data are the same bits on the wire, so opendnc
  always opens such ports 8-bit and does the parity itself; docs/tape.md#iso-code).
* **EIA** (RS-244): its own table, channels 1-4 = BCD, 5 = **odd** parity, 6/7 = zones,
  8 = end of block ("CR", 0x80). :data:`EIA_TABLE` is the one place the table lives; a
  correction is one line, and a profile may add or override characters
  (``Codec(eia_extra=...)``), as Okuma's special-code parameters do.

Values of the EIA table, and which of them are unconfirmed, are in docs/tape.md#eia-code.
"""

from __future__ import annotations

import enum
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

from opendnc.tape.errors import NoCodeError

DC1 = 0x11  # reader start / resume (XON)
DC2 = 0x12  # punch on
DC3 = 0x13  # reader stop (XOFF)
DC4 = 0x14  # punch off
NUL = 0x00  # blank tape: leader, trailer, feed
DEL = 0x7F  # rubout: all seven holes punched, ignored by a reader


class Code(enum.Enum):
    """The tape code of a line."""

    ISO = "iso"
    EIA = "eia"


# EIA RS-244 as byte values (channel n = bit n-1). Digits, letters, space, "-", "+", ".", ",",
# "/" after the IBM 1620 8-channel code RS-244 grew out of; "(" ")" after the Yaskawa table
# (docs/tape.md#eia-code). "%" stands for ER (end of record): its value is our choice, unconfirmed.
EIA_TABLE: Mapping[str, int] = MappingProxyType(
    {
        "0": 0x20, "1": 0x01, "2": 0x02, "3": 0x13, "4": 0x04,
        "5": 0x15, "6": 0x16, "7": 0x07, "8": 0x08, "9": 0x19,
        "A": 0x61, "B": 0x62, "C": 0x73, "D": 0x64, "E": 0x75,
        "F": 0x76, "G": 0x67, "H": 0x68, "I": 0x79, "J": 0x51,
        "K": 0x52, "L": 0x43, "M": 0x54, "N": 0x45, "O": 0x46,
        "P": 0x57, "Q": 0x58, "R": 0x49, "S": 0x32, "T": 0x23,
        "U": 0x34, "V": 0x25, "W": 0x26, "X": 0x37, "Y": 0x38,
        "Z": 0x29, " ": 0x10, "-": 0x40, "+": 0x70, ".": 0x6B,
        ",": 0x3B, "/": 0x31, "(": 0x1A, ")": 0x4A,
        "%": 0x0B,  # ER, end of record: unconfirmed (docs/tape.md#eia-code)
    }
)  # fmt: skip
EIA_EOB = 0x80  # channel 8 alone, "CR"
EIA_FEED = frozenset({NUL, DEL})  # blank tape and tape feed (all of channels 1-7)
_EIA_RAW = frozenset({NUL, DEL, DC1, DC2, DC3, DC4})


def even_parity(char: int) -> int:
    """``char`` (7 bits) with bit 8 set so the byte has an even number of ones."""
    return char | 0x80 if char.bit_count() & 1 else char


_ISO_PARITY = bytes(even_parity(c) for c in range(128)) + bytes(128)
# decoding an ISO byte with parity: 7-bit char, or 0xFF-marked as failing (see Codec.decode)
_ISO_GOOD = frozenset(even_parity(c) for c in range(128))


class Eob(enum.Enum):
    """End of block on the wire (docs/tape.md#end-of-block). EIA has only its own CR."""

    LF = "lf"
    CRLF = "crlf"
    CR = "cr"
    LFCRCR = "lfcrcr"

    @property
    def text(self) -> str:
        """The ISO characters of this EOB."""
        return {"lf": "\n", "crlf": "\r\n", "cr": "\r", "lfcrcr": "\n\r\r"}[self.value]


@dataclass(frozen=True)
class Codec:
    """Characters to wire bytes and back for one line: code, parity, EOB.

    ``encode_block`` turns one block's text (no line end) into wire bytes with the EOB;
    ``decode_byte`` turns one wire byte into a character, ``None`` for feed (NUL, DEL), or
    raises nothing itself: it returns a :class:`Bad` marker the reader turns into a typed
    error with the position.
    """

    code: Code = Code.ISO
    parity: bool = True  # ISO only: even parity in bit 8 (EIA always carries its own)
    eob: Eob = Eob.LF
    eia_extra: Mapping[str, int] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.code is Code.EIA:
            table = {**EIA_TABLE, **self.eia_extra}
            reverse = {value: char for char, value in table.items()}
            object.__setattr__(self, "_eia", table)
            object.__setattr__(self, "_eia_reverse", reverse)

    @property
    def eia_table(self) -> Mapping[str, int]:
        """The EIA table in use (the standard one plus ``eia_extra``)."""
        table: Mapping[str, int] = getattr(self, "_eia", EIA_TABLE)
        return table

    @property
    def eob_bytes(self) -> bytes:
        """The bytes of one end of block."""
        if self.code is Code.EIA:
            return bytes((EIA_EOB,))
        return self.encode_text(self.eob.text, 0)

    def encode_text(self, text: str, line: int) -> bytes:
        """Encode characters (no EOB inside); :class:`NoCodeError` names ``line``/column."""
        if self.code is Code.EIA:
            table = self.eia_table
            out = bytearray()
            for column, char in enumerate(text, start=1):
                value = table.get(char)
                if value is None and ord(char) in _EIA_RAW:
                    value = ord(char)  # feed and the DC codes are the same bytes in EIA
                if value is None:
                    raise NoCodeError(char, "EIA", line, column)
                out.append(value)
            return bytes(out)
        try:
            raw = text.encode("ascii")
        except UnicodeEncodeError as exc:
            raise NoCodeError(text[exc.start], "ISO", line, exc.start + 1) from None
        return raw.translate(_ISO_PARITY) if self.parity else raw

    def encode_block(self, text: str, line: int = 0) -> bytes:
        """One block: its characters and the EOB."""
        return self.encode_text(text, line) + self.eob_bytes

    def decode_byte(self, byte: int) -> str | Bad | None:
        """One wire byte as a character (CR and LF for ISO line ends, ``"\\n"`` for the EIA
        EOB), ``None`` for feed, or :class:`Bad` for a byte the code does not have."""
        if self.code is Code.EIA:
            if byte == EIA_EOB:
                return "\n"
            if byte in EIA_FEED:
                return None
            char = self._reverse().get(byte)
            if char is None:
                return Bad(byte, parity=byte.bit_count() % 2 == 0)
            return char
        if self.parity:
            if byte not in _ISO_GOOD:
                return Bad(byte, parity=True)
            byte &= 0x7F
        elif byte > 0x7F:
            return Bad(byte, parity=False)
        if byte in (NUL, DEL):
            return None
        return chr(byte)

    def _reverse(self) -> Mapping[int, str]:
        reverse: Mapping[int, str] = getattr(self, "_eia_reverse")  # noqa: B009
        return reverse


@dataclass(frozen=True, slots=True)
class Bad:
    """A wire byte with no character: ``parity`` true when it failed the parity check."""

    byte: int
    parity: bool


def iso_to_eia(text: str, *, line: int = 1) -> bytes:
    """Convert ISO program text (LF line ends) to EIA bytes, line by line."""
    codec = Codec(Code.EIA)
    out = bytearray()
    lines = text.split("\n")
    for number, block in enumerate(lines, start=line):
        if number - line == len(lines) - 1:
            out += codec.encode_text(block, number)  # no EOB after the last (open) line
        else:
            out += codec.encode_block(block, number)
    return bytes(out)


def eia_to_iso(data: bytes) -> str:
    """Convert EIA bytes back to ISO text (LF line ends); feed bytes are dropped.

    Raises :class:`~opendnc.tape.errors.TapeParityError` or
    :class:`~opendnc.tape.errors.TapeCharacterError` naming line and column."""
    from opendnc.tape.errors import TapeCharacterError, TapeParityError

    codec = Codec(Code.EIA)
    out: list[str] = []
    line, column = 1, 0
    for byte in data:
        char = codec.decode_byte(byte)
        if char is None:
            continue
        column += 1
        if isinstance(char, Bad):
            error = TapeParityError if char.parity else TapeCharacterError
            raise error(line, column, f"byte 0x{char.byte:02X}")
        out.append(char)
        if char == "\n":
            line, column = line + 1, 0
    return "".join(out)
