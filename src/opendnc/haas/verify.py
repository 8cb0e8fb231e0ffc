"""End-to-end checks of a program moved by checksum XModem (docs/xmodem.md#end-to-end-checks).

A Haas speaks XModem in checksum mode only, and an 8-bit sum lets two bit errors through when
they cancel (a ``3`` that became ``2`` and a ``t`` that became ``u`` in one block). Two checks
close that gap from outside the protocol:

* **punch back and compare** (:func:`compare`): after a load the operator punches the program
  back and the PC compares it, line by line, with what it sent; the control's own framing
  (leader, the LF before ``%``, the empty line before the closing ``%``, its EOB, SUB padding)
  is not part of the comparison;
* **a check line in the program** (:func:`add_check_line`, :func:`check_line`): a comment
  ``(ODNC CRC32 1A2B3C4D)`` holding the CRC-32 of the program's text, so a program punched at
  any later time can be checked by whoever receives it, without the original.

Both work on the program's *lines*: the text between the first and the last ``%`` line, split
at any line end, with trailing blanks and empty lines dropped. The check line's sum also drops
every blank and tab (a control with Setting 41 adds spaces between words when it punches).
"""

from __future__ import annotations

import re
import zlib
from dataclasses import dataclass

from opendnc.errors import TransferError
from opendnc.transport.base import ByteStream
from opendnc.xmodem.driver import EventHandler, Progress, receive
from opendnc.xmodem.framing import Mode
from opendnc.xmodem.haas import Eob, from_wire, program_header, strip_padding
from opendnc.xmodem.receiver import ReceiverConfig

__all__ = [
    "CheckLine",
    "CheckState",
    "Difference",
    "ProgramDamaged",
    "ProgramMismatch",
    "VerifyResult",
    "add_check_line",
    "check_line",
    "compare",
    "program_lines",
    "receive_punch",
    "verify_by_punch",
]

# what a punch may carry around the program: leader NULs, XON/XOFF/DC2/DC4, SUB padding
_FRAMING = bytes([0x00, 0x11, 0x12, 0x13, 0x14, 0x1A])
_LINE_END = re.compile(r"\r\n|\r|\n")
_CHECK = re.compile(r"^\(ODNC CRC32 ([0-9A-F]{8})\)$")
# our marker, or the shape of the line with a damaged marker: a comment that looks like a check
# line but does not parse is a damaged one (a user's own comments never look like this)
_CHECK_LIKE = re.compile(r"^\((?:ODNC\b|.{4} CRC32 )")
_BLANKS = str.maketrans("", "", " \t")


def program_lines(data: bytes) -> list[str]:
    """The program's lines, without tape framing (see the module doc)."""
    text = data.translate(None, _FRAMING).decode("latin-1")
    lines = [line.rstrip(" \t") for line in _LINE_END.split(text)]
    content = [line for line in lines if line.strip(" \t")]
    if content and content[0].strip() == "%":
        content = content[1:]
    if content and content[-1].strip() == "%":
        content = content[:-1]
    return content


@dataclass(frozen=True, slots=True)
class Difference:
    """The first line where the two programs differ (``None``: that program has ended)."""

    line: int  # 1 = the first line after the opening %
    sent: str | None
    punched: str | None


@dataclass(frozen=True, slots=True)
class VerifyResult:
    """The outcome of :func:`compare`."""

    verified: bool
    lines: int  # lines compared (of the sent program)
    program: str | None  # O-number of the sent program, e.g. "O01000"
    difference: Difference | None = None


class ProgramMismatch(TransferError):
    """The program the control punched back differs from the one sent."""

    def __init__(self, result: VerifyResult, what: str = "the program") -> None:
        diff = result.difference
        assert diff is not None
        sent = "its end" if diff.sent is None else repr(diff.sent)
        punched = "its end" if diff.punched is None else repr(diff.punched)
        super().__init__(
            f"{what} on the control differs at line {diff.line}: sent {sent}, punched {punched}"
        )
        self.result = result


def _canonical(line: str, ignore_spaces: bool) -> str:
    return line.translate(_BLANKS) if ignore_spaces else line


def compare(sent: bytes, punched: bytes, *, ignore_spaces: bool = False) -> VerifyResult:
    """Compare the program ``sent`` with what the control ``punched`` back.

    Line ends, tape framing and trailing blanks never count; ``ignore_spaces`` also ignores
    every blank (Setting 41, *add spaces RS-232 out*, makes the control punch them).
    """
    ours = program_lines(sent)
    theirs = program_lines(punched)
    header = program_header(sent)
    name = header.name if header is not None else None
    for index in range(max(len(ours), len(theirs))):
        a = ours[index] if index < len(ours) else None
        b = theirs[index] if index < len(theirs) else None
        if a is None or b is None or _canonical(a, ignore_spaces) != _canonical(b, ignore_spaces):
            return VerifyResult(False, len(ours), name, Difference(index + 1, a, b))
    return VerifyResult(True, len(ours), name)


# ----------------------------------------------------------------------------- check line
class CheckState:
    """What :func:`check_line` found (string constants, also used in JSON)."""

    OK = "ok"
    MISSING = "missing"
    MISMATCH = "mismatch"


@dataclass(frozen=True, slots=True)
class CheckLine:
    """The result of :func:`check_line`: ``state`` and the sums involved."""

    state: str
    expected: str | None  # the sum written in the program
    actual: str  # the sum of the program's text as it is now
    line: int | None  # where the check line is (1 = first line after %)

    @property
    def ok(self) -> bool:
        """True when the program carries a check line that matches its text."""
        return self.state == CheckState.OK


class ProgramDamaged(TransferError):
    """A program's check line does not match its text: it changed on the way."""

    def __init__(self, result: CheckLine, what: str = "the program") -> None:
        written = "a damaged check line" if result.expected is None else result.expected
        super().__init__(
            f"{what}: its check line (line {result.line}) says {written}, its text sums to "
            f"{result.actual}: damaged on the way; the file was not written, punch it again"
        )
        self.result = result


def _is_check_like(line: str) -> bool:
    return _CHECK_LIKE.match(line.strip()) is not None


def _sum(lines: list[str]) -> str:
    text = "\n".join(line.translate(_BLANKS) for line in lines)
    return f"{zlib.crc32(text.encode('latin-1')):08X}"


def check_line(data: bytes) -> CheckLine:
    """Find the program's ``(ODNC CRC32 …)`` line and check it against the text."""
    lines = program_lines(data)
    found = [(i, line) for i, line in enumerate(lines) if _is_check_like(line)]
    rest = [line for line in lines if not _is_check_like(line)]
    actual = _sum(rest)
    if not found:
        return CheckLine(CheckState.MISSING, None, actual, None)
    index, text = found[0]
    match = _CHECK.match(text.strip())
    expected = match.group(1) if match else None
    if len(found) > 1 or expected != actual:
        return CheckLine(CheckState.MISMATCH, expected, actual, index + 1)
    return CheckLine(CheckState.OK, expected, actual, index + 1)


def add_check_line(data: bytes) -> bytes:
    """``data`` with its check line (re)written after the O-number line.

    The program keeps its line ends (the first one found is used for the new line); an old
    check line is replaced.
    """
    text = data.decode("latin-1")
    eol_match = _LINE_END.search(text)
    eol = eol_match.group(0) if eol_match else "\n"
    raw_lines = _LINE_END.split(text)
    kept = [line for line in raw_lines if not _is_check_like(line)]
    body = eol.join(kept).encode("latin-1")
    line = f"(ODNC CRC32 {_sum(program_lines(body))})"
    # after the O-number line, else after the opening %, else first
    position = 0
    for i, raw in enumerate(kept):
        stripped = raw.strip(" \t\x00")
        if stripped == "%":
            position = i + 1
            continue
        if stripped:
            position = i + 1 if re.match(r"O\d{1,5}\b", stripped) else position
            break
    kept.insert(position, line)
    return eol.join(kept).encode("latin-1")


# ----------------------------------------------------------------------------- punch back
def receive_punch(
    stream: ByteStream,
    *,
    eob: Eob = Eob.LF,
    timeout: float = 300.0,
    config: ReceiverConfig | None = None,
    progress: Progress | None = None,
    on_event: EventHandler | None = None,
) -> bytes:
    """Wait up to ``timeout`` s for the control to punch a program; its bytes, LF line ends.

    Checksum mode (all a Haas speaks), with the NC-text check on every block: a block that
    passed the sum but is no program text is asked for again (docs/nc-text.md).
    """
    config = config or ReceiverConfig(
        start_timeout=timeout, idle_timeout=max(30.0, min(timeout, 120.0)), text_check=True
    )
    parts: list[bytes] = []
    receive(
        stream,
        parts.append,
        mode=Mode.CHECKSUM,
        config=config,
        progress=progress,
        on_event=on_event,
    )
    return from_wire(strip_padding(b"".join(parts)), eob)


def verify_by_punch(
    stream: ByteStream,
    sent: bytes,
    *,
    eob: Eob = Eob.LF,
    timeout: float = 300.0,
    ignore_spaces: bool = False,
    progress: Progress | None = None,
    on_event: EventHandler | None = None,
) -> VerifyResult:
    """Receive the control's punch of the program just loaded and compare it with ``sent``.

    Raises :class:`ProgramMismatch` when they differ (the control holds other bytes, or the
    punch was damaged on the way: punch it again to tell the two apart).
    """
    punched = receive_punch(stream, eob=eob, timeout=timeout, progress=progress, on_event=on_event)
    result = compare(sent, punched, ignore_spaces=ignore_spaces)
    if not result.verified:
        raise ProgramMismatch(result, result.program or "the program")
    return result
