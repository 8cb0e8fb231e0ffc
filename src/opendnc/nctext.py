"""Does a file read as the text of an NC program? The byte-level check behind XModem and DNC.

Checksum-mode XModem (the only mode a Haas speaks) cannot see two bit errors whose changes
cancel in its 8-bit sum, so a damaged block can arrive as "good". The protocol is blind, but
the text is not: an NC program is a small set of printable characters, and a bit error often
makes a byte no program holds. The rules (docs/nc-text.md gives the reasons and sources):

* the **leader** (before the first other byte) and **trailer** (after the last one) may hold
  tape codes: NUL (blank tape), DC2/DC4 (punch on/off in Haas "DC codes" mode), SUB (XModem
  padding), DEL (rubout), besides spaces, tabs and line ends;
* the **body** holds printable ASCII (0x20-0x7E), TAB, LF and CR, nothing else: no other
  control character, no tape code, no byte above 0x7F;
* outside a comment ``( ... )`` address letters are upper case: a lower-case letter there is
  refused (one flipped bit turns ``G`` into ``g`` and ``1`` into ``q``).

A block is a line; the first problem is reported with its line, column and byte offset.
:class:`TextScanner` checks a file of any size in pieces; :func:`check_program` checks bytes.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from opendnc.errors import InputError, ProgramTextError

TAPE_CODES = frozenset({0x00, 0x12, 0x14, 0x1A, 0x7F})  # NUL, DC2, DC4, SUB, DEL
_BLANK = b"\t\n\r "
_LEADER_TRAILER = bytes(sorted(TAPE_CODES)) + _BLANK

# What the scanner stops at: a comment (to its ')' or the end of its line), a byte outside
# printable ASCII + TAB/LF/CR, or a lower-case letter. Comments are matched as one token so
# their lower-case text is skipped; a bad byte inside a comment ends the match and is found.
_COMMENT_BODY = rb"[\t\x20-\x28\x2a-\x7e]*"
_TOKEN = re.compile(rb"\(" + _COMMENT_BODY + rb"\)?|[^\t\n\r\x20-\x7e]|[a-z]")
_COMMENT_REST = re.compile(_COMMENT_BODY + rb"\)?")
# the bytes no _TOKEN match starts with: TAB, LF, CR and printable ASCII but "(" and a-z
_NO_TOKEN = bytes(
    b
    for b in range(256)
    if b in b"\t\n\r" or (0x20 <= b <= 0x7E and b != 0x28 and not 0x61 <= b <= 0x7A)
)
_LINE_END = re.compile(rb"\r\n?|\n")
CHUNK = 1 << 20  # bytes per read when checking a file


@dataclass(frozen=True, slots=True)
class TextProblem:
    """The first byte that is not NC program text: where it is and why it does not belong."""

    line: int  # 1-based block (line) number
    column: int  # 1-based byte position in the line
    offset: int  # 0-based byte offset in the file
    byte: int
    reason: str

    def describe(self) -> str:
        """E.g. ``byte 0x02 (a control character) at line 160, column 21, offset 3349 ...``."""
        return (
            f"byte 0x{self.byte:02X} ({self.reason}) at line {self.line}, column {self.column}, "
            f"offset {self.offset} (NC block {self.line})"
        )


def _reason(byte: int) -> str:
    if byte in TAPE_CODES:
        return "a tape code inside the program"
    if byte < 0x20:
        return "a control character"
    if byte >= 0x80:
        return "not ASCII"
    return "a lower-case letter outside a comment"


class TextScanner:
    """Checks NC program text fed in pieces of any size; remembers the first problem.

    ``feed()`` pieces in order, then ``finish()``: it returns the first :class:`TextProblem`
    or ``None``. Once a problem is certain, later input is ignored.
    """

    def __init__(self) -> None:
        self._offset = 0  # file offset of the start of the next piece
        self._lines = 0  # line ends seen in earlier pieces
        self._line_start = 0  # file offset where the current line began
        self._cr_pending = False  # the previous piece ended in CR (maybe half a CR LF)
        self._started = False  # past the leader
        self._in_comment = False  # the previous piece ended inside an open comment
        self._pending: TextProblem | None = None  # a tape code: the problem if body follows
        self.problem: TextProblem | None = None

    def feed(self, data: bytes) -> None:
        """Check the next piece of the file."""
        if self.problem is not None or not data:
            return
        base = self._offset
        pos = 0
        if self._pending is not None:
            # a tape code met earlier: fine if only the trailer follows, else it is the problem
            if data.strip(_LEADER_TRAILER):
                self.problem = self._pending
                return
            self._advance(data)
            return
        if not self._started:
            stripped = data.lstrip(_LEADER_TRAILER)
            pos = len(data) - len(stripped)
            if not stripped:
                self._advance(data)
                return
            self._started = True
        if self._in_comment:
            match = _COMMENT_REST.match(data, pos)
            assert match is not None  # the pattern matches the empty string
            pos = match.end()
            self._in_comment = pos == len(data) and not match.group().endswith(b")")
        # most pieces of a program hold no byte a token starts with: deleting every other
        # byte (in C) shows that sooner than the search, which tries each byte in turn
        tokens = bool(data.translate(None, _NO_TOKEN))
        while tokens and (match := _TOKEN.search(data, pos)) is not None:
            token = match.group()
            pos = match.end()
            if token[0] == 0x28:  # '(' starts a comment
                self._in_comment = pos == len(data) and not token.endswith(b")")
                continue
            problem = self._locate(data, base + match.start(), token[0])
            if problem.byte in TAPE_CODES and not data[pos:].strip(_LEADER_TRAILER):
                self._pending = problem  # the trailer begins here, unless body follows later
                break
            self.problem = problem
            return
        self._advance(data)

    @property
    def offset(self) -> int:
        """Bytes fed so far: the file offset where the next piece begins."""
        return self._offset

    def copy(self) -> TextScanner:
        """An independent scanner in the same state (to try a piece before keeping it)."""
        twin = TextScanner.__new__(TextScanner)
        twin.__dict__.update(self.__dict__)
        return twin

    def finish(self) -> TextProblem | None:
        """End of file: the first problem, or None if the text is clean."""
        return self.problem

    # -- bookkeeping: line numbers are counted per piece, in C, not per byte ----------------

    def _advance(self, data: bytes) -> None:
        self._lines += self._count_lines(data, len(data))
        last = max(data.rfind(b"\n"), data.rfind(b"\r"))
        if last >= 0:
            self._line_start = self._offset + last + 1
        self._cr_pending = data.endswith(b"\r")
        self._offset += len(data)

    def _count_lines(self, data: bytes, end: int) -> int:
        # the matches of _LINE_END, counted without making them: every LF and CR ends a
        # line, except the CR of a CR LF pair
        count = data.count(b"\n", 0, end)
        if data.find(b"\r", 0, end) >= 0:
            count += data.count(b"\r", 0, end) - data.count(b"\r\n", 0, end)
        if self._cr_pending and end > 0 and data.startswith(b"\n"):
            count -= 1  # the LF of a CR LF cut between two pieces
        return count

    def _locate(self, data: bytes, offset: int, byte: int) -> TextProblem:
        """The problem at file ``offset``, which lies in ``data`` (the current piece)."""
        local = offset - self._offset
        line_start = self._line_start
        last = max(data.rfind(b"\n", 0, local), data.rfind(b"\r", 0, local))
        if last >= 0:
            line_start = self._offset + last + 1
        return TextProblem(
            line=self._lines + self._count_lines(data, local) + 1,
            column=offset - line_start + 1,
            offset=offset,
            byte=byte,
            reason=_reason(byte),
        )


def find_problem(data: bytes) -> TextProblem | None:
    """The first byte of ``data`` that is not NC program text, or None."""
    scanner = TextScanner()
    scanner.feed(data)
    return scanner.finish()


def check_program(data: bytes, *, what: str = "program", action: str = "refused") -> None:
    """Raise :class:`ProgramTextError` if ``data`` is not NC program text."""
    problem = find_problem(data)
    if problem is not None:
        raise ProgramTextError(problem, what=what, action=action)


def check_program_file(path: Path, *, what: str = "", action: str = "not sent") -> None:
    """Check the file at ``path`` in pieces; raise :class:`ProgramTextError` on a problem.

    ``what`` names the program in the message (default: the file name).
    """
    scanner = TextScanner()
    try:
        with path.open("rb") as handle:
            while (piece := handle.read(CHUNK)) and scanner.problem is None:
                scanner.feed(piece)
    except OSError as exc:
        raise InputError(f"cannot read {path}: {exc.strerror or exc}") from exc
    problem = scanner.finish()
    if problem is not None:
        raise ProgramTextError(problem, what=what or path.name, action=action)
