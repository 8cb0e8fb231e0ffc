"""A program file as tape blocks on the wire, framed and coded for one profile.

:class:`TapeFeed` is the :class:`~opendnc.haas.dnc_engine.ProgramFeed` of the tape engine:
the drip-feed run (:class:`~opendnc.haas.dnc_engine.DncRun`) and a plain send pull wire
bytes from it line by line (constant memory), and it keeps the run's accounting
(``done_at``, ``lines``, ``plan``). What it adds:

* framing per profile (:class:`~opendnc.tape.profiles.Framing`): ``%`` lines, Okuma's
  ``$NAME.MIN``, Siemens' ``%_N_NAME_MPF`` + ``;$PATH=`` header, Fagor's ``%name,MX,``,
  and the end-of-file byte;
* comments stripped when the profile asks, a space added to odd blocks under TV check;
* every character coded by the profile's codec (ISO with parity, or EIA; a character
  without a code is a :class:`~opendnc.tape.errors.NoCodeError` naming line and column);
* a restart from a line with the dialect's preamble (:mod:`opendnc.tape.dialects`).
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

from opendnc.errors import InputError
from opendnc.haas.dnc_engine import ProgramFeed
from opendnc.haas.modal import ModalState, track
from opendnc.tape.codes import Codec
from opendnc.tape.dialects import dialect_preamble, get_dialect
from opendnc.tape.naming import okuma_name, siemens_name
from opendnc.tape.profiles import Framing, Profile
from opendnc.xmodem.haas import Eob as HaasEob

_COMMENT = re.compile(r"\([^)]*\)?")
HEAD_LINES = 8  # lines looked at for a program's header and name


def strip_comment(text: str) -> str:
    """``text`` without its ``( ... )`` comments (a block of only a comment becomes empty)."""
    return _COMMENT.sub("", text).rstrip()


def tv_pad(text: str) -> str:
    """``text`` with a space added when it has an odd number of characters."""
    return text + " " if len(text) % 2 else text


class TapeFeed(ProgramFeed):
    """Wire bytes of ``path`` for ``profile``, block by block; see the module doc."""

    def __init__(
        self,
        path: Path,
        profile: Profile,
        *,
        from_line: int = 1,
        retract: bool = True,
        codec: Codec | None = None,
    ) -> None:
        super().__init__(path, eob=HaasEob.LF, from_line=from_line, retract=retract)
        self.profile = profile
        self.codec = codec or profile.codec()
        self.warnings: tuple[str, ...] = ()

    def block(self, text: str, line: int = 0) -> bytes:
        """One block on the wire: comments, TV pad and code applied."""
        profile = self.profile
        if profile.strip_comments:
            text = strip_comment(text)
        if profile.tv_check and not text.startswith("%"):
            text = tv_pad(text)
        return self.codec.encode_block(text, line)

    def _opening(self, first: str) -> tuple[list[str], bool]:
        """Blocks that open the record, and whether they replace the file's first line."""
        framing = self.profile.framing
        first = first.strip()
        own = first.startswith("%")
        if framing is Framing.PERCENT:
            return ["%"], own
        if framing is Framing.OKUMA:
            return [f"${okuma_name(self.path)}", "%"], own
        if framing is Framing.SIEMENS:
            if own and first != "%":
                return [], False  # the file's own %_N_..._MPF header
            name = siemens_name(self.path)
            return [f"%_N_{name}_MPF", f";$PATH={self.profile.path}"], own
        if own and first != "%":
            return [], False  # Fagor: the file's own %comment,MX,
        return [f"%{self.path.stem[:20]},MX,"], own

    def __iter__(self) -> Iterator[bytes]:
        profile = self.profile
        closing = profile.framing in (Framing.PERCENT, Framing.OKUMA)
        lines = self._read_lines()
        first: tuple[int, str, int] | None = None
        for item in lines:
            if item[1].strip():
                first = item
                break
        opening, replaces_first = self._opening(first[1] if first else "")
        for text in opening:
            self.lines += 1
            yield self.block(text)
        rest: Iterator[tuple[int, str, int]] = lines
        if first is not None and not replaces_first:
            rest = _chain(first, lines)
        last = ""
        if self.from_line > 1:
            rest = self._restart(rest)
        for number, text, done in rest:
            stripped = text.strip()
            if not stripped:
                self.done_at = done
                continue
            if stripped == "%" and not closing:
                self.done_at = done
                continue  # Siemens and Fagor records have no closing %
            if profile.strip_comments and not strip_comment(text).strip():
                self.done_at = done
                continue
            last = stripped
            self.done_at = done
            self.lines += 1
            yield self.block(text, number)
        self.done_at = self.position
        if closing and last != "%":
            self.lines += 1
            yield self.block("%")
        if profile.eof_byte is not None:
            yield self.codec.encode_text(chr(profile.eof_byte), 0)

    def _restart(self, lines: Iterator[tuple[int, str, int]]) -> Iterator[tuple[int, str, int]]:
        """Scan the lines before ``from_line``; yield the preamble, then line N onward."""
        state = ModalState()
        before = self.done_at
        head: list[tuple[int, str, int]] = []  # a Siemens or Fagor header is kept
        for number, text, done in lines:
            if number >= self.from_line:
                yield from head
                plan = dialect_preamble(
                    state, self.from_line, get_dialect(self.profile.dialect), retract=self.retract
                )
                self.plan = plan
                self.warnings = plan.warnings
                self.done_at = before
                for block in plan.preamble:
                    yield 0, block, before
                yield number, text, done
                yield from lines
                return
            before = done
            stripped = text.strip()
            if (stripped.startswith("%") and stripped != "%") or stripped.startswith(";$PATH="):
                head.append((number, text, done))
            state = track(state, text)
        raise InputError(f"{self.path} has fewer than {self.from_line} lines")


def _chain(
    first: tuple[int, str, int], rest: Iterator[tuple[int, str, int]]
) -> Iterator[tuple[int, str, int]]:
    yield first
    yield from rest


def program_wire(path: Path, profile: Profile, *, codec: Codec | None = None) -> bytes:
    """The whole record of ``path`` as the wire carries it, without leader and trailer."""
    feed = TapeFeed(path, profile, codec=codec)
    try:
        return b"".join(feed)
    finally:
        feed.close()


def leader_bytes(profile: Profile, count: int, codec: Codec | None = None) -> bytes:
    """``count`` feed characters of ``profile`` (NUL, or space where chosen), coded."""
    if count <= 0:
        return b""
    return (codec or profile.codec()).encode_text(chr(profile.feed_byte) * count, 0)
