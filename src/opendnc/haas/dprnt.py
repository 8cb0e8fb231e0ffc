"""DPRNT: the Haas formatted-output statement, both ends of it.

Sans-IO, used by the virtual control (to print) and by the listener (to capture):

* :func:`format_value` applies the ``#var[wf]`` rules of the Haas mill manual:
  ``w`` places for the whole part and ``f`` for the fraction, ``1 <= w + f <= 8``;
  the fraction is rounded to its last place and keeps trailing zeros; the decimal point
  is omitted when ``f == 0`` and the whole part is then truncated, not rounded (the manual
  prints ``1`` for 1.5436 with ``[40]``); a whole part shorter than ``w`` is padded with
  leading spaces, a longer one grows the field (never truncated).
* :func:`parse_statement` turns ``DPRNT[...]`` source into typed items; each ``*`` in text
  prints as a space.
* :class:`DprntLineFramer` cuts a captured byte stream into lines (CR, LF or CR LF), drops
  the device-control bytes a Haas may send around DPRNT output (NUL, DC1..DC4), drops an
  over-long line whole, and marks a line cut by the end of the link.
* :func:`parse_line` finds the labelled numbers in a captured line.

Where the manual is silent we chose, and document here: a minus sign is written directly
before the first digit and counts as one of the ``w`` places; an undefined (null) variable
prints as zero.
"""

from __future__ import annotations

import collections
import math
import re
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from decimal import ROUND_DOWN, ROUND_HALF_UP, Decimal, InvalidOperation

from opendnc.errors import InputError
from opendnc.haas.mdc import LINE_NOISE

MAX_PLACES = 8
"""Largest ``w + f`` the control accepts in a ``#var[wf]`` format."""

MAX_LINE = 4096
"""Longest captured line kept, in bytes; a longer one is dropped whole and reported."""


@dataclass(frozen=True, slots=True)
class Text:
    """Literal text of a DPRNT statement, ``*`` already turned into spaces."""

    text: str


@dataclass(frozen=True, slots=True)
class Variable:
    """A ``#number[wf]`` item: print macro variable ``number`` with ``whole``.``frac`` places."""

    number: int
    whole: int
    frac: int


Item = Text | Variable


def check_format(whole: int, frac: int) -> None:
    """Raise :class:`InputError` unless ``[whole frac]`` is a legal DPRNT format."""
    if whole < 0 or frac < 0 or not 1 <= whole + frac <= MAX_PLACES:
        raise InputError(
            f"illegal DPRNT format [{whole}{frac}]: whole + fraction places must be 1..{MAX_PLACES}"
        )


def format_value(value: float | None, whole: int, frac: int) -> str:
    """Format ``value`` as the control prints ``#var[whole frac]``.

    >>> format_value(1.5436, 4, 4)
    '   1.5436'
    >>> format_value(1.5436, 0, 3)
    '1.544'
    >>> format_value(1.5436, 4, 0)
    '   1'
    """
    check_format(whole, frac)
    number = 0.0 if value is None else value
    if not math.isfinite(number):
        raise InputError(f"cannot print {number!r} with DPRNT")
    try:
        exact = Decimal(repr(number))
        if frac == 0:
            shown = exact.quantize(Decimal(1), rounding=ROUND_DOWN)
        else:
            shown = exact.quantize(Decimal(1).scaleb(-frac), rounding=ROUND_HALF_UP)
    except InvalidOperation as exc:  # more digits than Decimal's context allows
        raise InputError(f"value {number!r} too large for DPRNT") from exc
    negative = shown < 0
    digits = f"{abs(shown):f}"
    if "." not in digits and frac:
        digits += "." + "0" * frac
    whole_digits, _, frac_digits = digits.partition(".")
    body = ("-" if negative else "") + whole_digits
    text = body.rjust(whole) if whole else body
    return f"{text}.{frac_digits}" if frac else text


_VAR = re.compile(r"#(\d{1,5})\[(\d)(\d)\]")


def parse_statement(source: str) -> tuple[Item, ...]:
    """Parse ``DPRNT[...]`` (the whole statement) into text and variable items.

    Raises :class:`InputError` naming the fault for a malformed statement or an illegal format.
    """
    stripped = source.strip()
    if not stripped.upper().startswith("DPRNT"):
        raise InputError(f"not a DPRNT statement: {source!r}")
    rest = stripped[5:].lstrip()
    if not rest.startswith("[") or not rest.endswith("]"):
        raise InputError(f"DPRNT needs its text in brackets: {source!r}")
    return parse_body(rest[1:-1])


def parse_body(body: str) -> tuple[Item, ...]:
    """Parse the text between ``DPRNT[`` and the closing ``]``."""
    items: list[Item] = []
    pos = 0
    text: list[str] = []
    while pos < len(body):
        char = body[pos]
        if char == "#":
            match = _VAR.match(body, pos)
            if match is None:
                raise InputError(f"DPRNT variable needs the form #nnnn[wf] at: {body[pos:]!r}")
            whole, frac = int(match.group(2)), int(match.group(3))
            check_format(whole, frac)
            if text:
                items.append(Text("".join(text)))
                text = []
            items.append(Variable(int(match.group(1)), whole, frac))
            pos = match.end()
            continue
        if char in "[]":
            raise InputError(f"unexpected {char!r} in DPRNT text: {body!r}")
        if not char.isprintable():
            raise InputError(f"unprintable character {char!r} in DPRNT text")
        text.append(" " if char == "*" else char)
        pos += 1
    if text:
        items.append(Text("".join(text)))
    return tuple(items)


def render(items: tuple[Item, ...], lookup: Callable[[int], float | None]) -> str:
    """Render parsed items to the printed line (without its line end)."""
    parts: list[str] = []
    for item in items:
        if isinstance(item, Text):
            parts.append(item.text)
        else:
            parts.append(format_value(lookup(item.number), item.whole, item.frac))
    return "".join(parts)


# --------------------------------------------------------------------------- capture side


@dataclass(frozen=True, slots=True)
class FramedLine:
    """A line cut from the stream. ``complete`` is False for the unfinished tail that
    :meth:`DprntLineFramer.end_of_stream` hands back when the link ended before its line end."""

    text: str
    complete: bool = True


@dataclass(frozen=True, slots=True)
class DroppedLine:
    """A line longer than the framer's limit, dropped whole (none of it is a line).

    ``length`` counts the bytes received of it (device-control bytes not counted);
    ``complete`` is False when the link ended before its line end.
    """

    length: int
    complete: bool = True


FrameEvent = FramedLine | DroppedLine

_EOL = re.compile(rb"\r\n|\r|\n")


class DprntLineFramer:
    """Cut a DPRNT byte stream into :class:`FramedLine` and :class:`DroppedLine` events.

    CR, LF and CR LF all end a line (Haas documents CR; NGC over TCP is seen with others);
    a CR LF split across two ``feed`` calls still counts as one line end.

    A line longer than ``max_line`` bytes is dropped whole: the framer stops keeping it when it
    grows past the limit, discards the rest of it up to its line end, and then reports one
    :class:`DroppedLine`. Lines before and after it are unaffected, however the bytes were cut
    into reads, and no piece of a dropped line is ever reported as a line. :meth:`feed` never
    raises: any byte string is legal input.
    """

    def __init__(self, max_line: int = MAX_LINE) -> None:
        self._buf = bytearray()
        self._events: collections.deque[FrameEvent] = collections.deque()
        self._max = max_line
        self._after_cr = False
        self._dropping = False
        self._dropped = 0

    def feed(self, data: bytes) -> None:
        """Add received bytes; complete lines (and dropped ones) become events."""
        # NUL leader, XON/XOFF, POPEN/PCLOS's DC2/DC4, and an XModem receiver's NAK, CAN and
        # SUB on a port that also loads programs: none is ever printed text (docs/haas.md#dprnt)
        data = data.translate(None, LINE_NOISE)
        if not data:
            return
        if self._after_cr and data[0] == 0x0A:
            data = data[1:]  # the LF of a CR LF that was split across two reads
        self._after_cr = data.endswith(b"\r")
        pos = 0
        for match in _EOL.finditer(data):
            self._take(data[pos : match.start()])
            self._end_line()
            pos = match.end()
        self._take(data[pos:])

    def _take(self, chunk: bytes) -> None:
        if self._dropping:
            self._dropped += len(chunk)
        elif len(self._buf) + len(chunk) > self._max:
            # too long: stop keeping it, but go on counting it up to its line end
            self._dropping = True
            self._dropped = len(self._buf) + len(chunk)
            self._buf.clear()
        else:
            self._buf += chunk

    def _end_line(self) -> None:
        if self._dropping:
            self._events.append(DroppedLine(self._dropped))
            self._dropping, self._dropped = False, 0
        else:
            self._events.append(FramedLine(self._buf.decode("latin-1")))
            self._buf.clear()

    def next_event(self) -> FrameEvent | None:
        """Return the next event, or ``None`` when more bytes are needed."""
        return self._events.popleft() if self._events else None

    def events(self) -> Iterator[FrameEvent]:
        """Yield every event produced so far."""
        while (event := self.next_event()) is not None:
            yield event

    def end_of_stream(self) -> FrameEvent | None:
        """The link ended: return what was left of an unfinished line, if anything.

        An unfinished line is returned as ``FramedLine(text, complete=False)`` (received
        text is never lost, but it is marked as cut); an unfinished over-long line as
        ``DroppedLine(length, complete=False)``. The framer is then ready for a new link.
        """
        self._after_cr = False
        if self._dropping:
            event: FrameEvent = DroppedLine(self._dropped, complete=False)
            self._dropping, self._dropped = False, 0
            return event
        if not self._buf:
            return None
        tail = self._buf.decode("latin-1")
        self._buf.clear()
        return FramedLine(tail, complete=False)


@dataclass(frozen=True, slots=True)
class Field:
    """One number found in a line, with the label written right before it (may be empty)."""

    label: str
    value: float


@dataclass(frozen=True, slots=True)
class ParsedLine:
    """A captured DPRNT line: its raw text, every number in order, and labelled fields."""

    text: str
    fields: tuple[Field, ...]

    @property
    def numbers(self) -> tuple[float, ...]:
        """Every number in the line, in order."""
        return tuple(f.value for f in self.fields)

    def get(self, label: str) -> float | None:
        """Value of the first field labelled ``label`` (case-insensitive), else ``None``."""
        wanted = label.upper()
        for f in self.fields:
            if f.label.upper() == wanted:
                return f.value
        return None


# A label is the run of letters directly (or after padding spaces) before a number; the sign
# belongs to the number, which DPRNT may separate from the label by padding spaces.
_NUMBER = re.compile(
    r"(?:(?P<label>[A-Za-z_]+)[ \t]*[:=]?[ \t]*)?(?P<num>[+-]?(?:\d+\.?\d*|\.\d+))"
)


def parse_line(text: str) -> ParsedLine:
    """Find labelled numbers in a DPRNT line; never fails on any text."""
    fields: list[Field] = []
    for match in _NUMBER.finditer(text):
        value = float(match.group("num"))  # the regex only matches float syntax
        if not math.isfinite(value):  # hundreds of digits overflow; not a DPRNT number
            continue
        fields.append(Field(match.group("label") or "", value))
    return ParsedLine(text, tuple(fields))
