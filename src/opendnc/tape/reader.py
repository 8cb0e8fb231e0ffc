"""Reading tape text off the wire (sans-IO): bytes in, blocks and the end of the record out.

:class:`TapeReader` is what both ends of a punch use: the PC receiving a punched program
and the virtual control reading one. It

* drops feed (NUL, DEL; EIA blank tape) anywhere and spaces before the first character;
* takes DC2 (punch on) as the start and DC4 (punch off) as the end when ``dc_codes`` is on;
  DC1/DC3 are flow control, never text (in EIA mode only DC1, DC2 and DC4: DC3's byte 0x13
  is the EIA digit 3; docs/tape.md#dc-codes);
* checks each character's parity and code (a typed error names the block and column);
* cuts blocks at any end of block: LF, CR LF, CR or LF CR CR (the EOB the control was set
  to is not needed to read it), EIA's channel-8 "CR";
* follows the ``%`` framing: blocks before the first block starting with ``%`` are the
  label section (kept apart, e.g. Okuma's ``$NAME.MIN``); a ``%`` starting a block after the
  opening one ends the record at once; with TV check on, every block in between must hold
  an even number of characters (comments and spaces count, the EOB does not);
* ends on DC4, on the profile's end-of-file byte (Siemens, Fagor) or the closing ``%``.

Limits turn endless garbage into a typed error: ``max_bytes`` counts every wire byte (feed
and DC codes too: a noisy line or a control sending feed for ever must end), ``max_block`` the
characters of a block, ``max_leader`` the feed before the record's first character (a leader
is legitimately long, but not endless; docs/tape.md#leader-label-and-tv-check).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

from opendnc.tape.codes import DC1, DC2, DC3, DC4, Bad, Code, Codec
from opendnc.tape.errors import TapeCharacterError, TapeParityError, TvCheckError


class End(enum.Enum):
    """Why a record ended."""

    PERCENT = "%"
    DC4 = "DC4"
    EOF = "end-of-file byte"
    QUIET = "quiet line"


@dataclass(frozen=True, slots=True)
class ReaderConfig:
    """How to read: the codec, TV check, and what ends a record."""

    codec: Codec = field(default_factory=Codec)
    tv_check: bool = False
    end_at_percent: bool = True
    dc_codes: bool = True
    eof_char: str | None = None  # e.g. "\x1a" (SUB) on Siemens
    max_block: int = 4096
    max_bytes: int = 16 << 20
    max_leader: int = 1 << 16  # feed bytes (NUL, DEL, blank, space) before the first character


class TapeReader:
    """Feed wire bytes with :meth:`feed`; read :attr:`blocks`, :attr:`ended`, :meth:`text`.

    ``feed`` returns the number of bytes it consumed: all of them unless the record ended,
    in which case the rest (a trailer, DC4, the next record) is left to the caller.
    """

    def __init__(self, config: ReaderConfig | None = None) -> None:
        self.config = config or ReaderConfig()
        self.blocks: list[str] = []
        self.opening: int | None = None  # index of the block starting with %
        self.ended: End | None = None
        self.dc2 = False  # DC2 seen
        self.received = 0  # wire bytes fed
        self.characters = 0  # characters read (not feed, not DC codes, not leading spaces)
        self.leader = 0  # feed bytes before the first character
        self._block: list[str] = []
        self._after_lf = False
        self._after_cr = False
        self._eia = self.config.codec.code is Code.EIA
        self._dc = {DC1, DC2, DC4} if self._eia else {DC1, DC2, DC3, DC4}

    @property
    def line(self) -> int:
        """1-based number of the block being read."""
        return len(self.blocks) + 1

    @property
    def started(self) -> bool:
        """Any character (not feed, not DC code) arrived."""
        return bool(self.blocks or self._block)

    def feed(self, data: bytes) -> int:
        """Read ``data``; raise a :class:`~opendnc.tape.errors.TapeWireError` on bad input."""
        config = self.config
        decode = config.codec.decode_byte
        for index, byte in enumerate(data):
            if self.ended is not None:
                return index
            # every byte counts, before anything may skip it: feed and DC codes included
            self.received += 1
            if self.received > config.max_bytes:
                raise TapeCharacterError(
                    self.line, len(self._block) + 1, f"more than {config.max_bytes} bytes"
                )
            if config.dc_codes and (byte if self._eia else byte & 0x7F) in self._dc:
                self._control(byte & 0x7F)
                continue
            char = decode(byte)
            if isinstance(char, Bad):
                error = TapeParityError if char.parity else TapeCharacterError
                raise error(self.line, len(self._block) + 1, f"byte 0x{char.byte:02X}")
            if char is None or (char == " " and not self.started):
                if not self.started:  # leader: feed (or spaces) before the first character
                    self.leader += 1
                    if self.leader > config.max_leader:
                        raise TapeCharacterError(
                            1, 1, f"more than {config.max_leader} feed bytes before the program"
                        )
                continue
            self.characters += 1
            self._char(char)
        return len(data)

    def _control(self, code: int) -> None:
        if code == DC2:
            self.dc2 = True
        elif code == DC4 and (self.dc2 or self.started):
            self._finish(End.DC4)

    def _char(self, char: str) -> None:
        if char == "\n":
            if self._after_cr:  # the LF of CR LF
                self._after_cr = False
                return
            self._end_block()
            self._after_lf = True
            return
        if char == "\r":
            if self._after_lf:  # the CRs of LF CR CR
                return
            self._end_block()
            self._after_cr = True
            return
        self._after_lf = self._after_cr = False
        if char == self.config.eof_char:
            self._finish(End.EOF)
            return
        if (
            char == "%"
            and not self._block
            and self.opening is not None
            and self.config.end_at_percent
        ):
            self._block.append(char)
            self._end_block(check=False)
            self._finish(End.PERCENT)
            return
        if len(self._block) >= self.config.max_block:
            raise TapeCharacterError(
                self.line, len(self._block) + 1, f"block longer than {self.config.max_block}"
            )
        self._block.append(char)

    def _end_block(self, *, check: bool = True) -> None:
        text = "".join(self._block)
        self._block.clear()
        if check and self.config.tv_check and self.opening is not None and len(text) % 2:
            raise TvCheckError(self.line, len(text), f"{len(text)} characters")
        if self.opening is None and text.startswith("%"):
            self.opening = len(self.blocks)
        self.blocks.append(text)

    def _finish(self, why: End) -> None:
        if self._block:
            self._end_block(check=False)  # a last block without EOB before DC4 / EOF
        self.ended = why

    def quiet(self) -> None:
        """The line went quiet: end the record here (the caller decides if that is normal)."""
        if self.ended is None:
            self._finish(End.QUIET)

    @property
    def label(self) -> list[str]:
        """Blocks before the opening ``%`` block (empty when there is none)."""
        return self.blocks[: self.opening] if self.opening is not None else []

    @property
    def program(self) -> list[str]:
        """The record's blocks: from the opening ``%`` (or the first block) to the end."""
        return self.blocks[self.opening :] if self.opening is not None else list(self.blocks)

    @property
    def closed(self) -> bool:
        """The record ended with its closing ``%``."""
        return self.ended is End.PERCENT

    def text(self) -> str:
        """The record as program text with LF line ends."""
        lines = self.program
        while lines and not lines[-1].strip() and self.ended is not End.PERCENT:
            lines = lines[:-1]
        return "".join(line + "\n" for line in lines)
