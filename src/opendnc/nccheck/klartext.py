"""The Heidenhain conversational (Klartext) dry run.

Each line ``N KEYWORD ...`` is parsed into a :class:`_Line`; lines without a block number
after a ``CYCL DEF`` (or ending in ``~``) are its parameters. The run then executes the
blocks: ``BEGIN``/``END PGM``, ``BLK FORM``, ``TOOL DEF``/``TOOL CALL``, straight and circular
paths (``L``, ``CC``, ``C``, ``CR``, ``CT``, ``RND``, ``CHF``, polar ``LP``/``CP``), labels
(``LBL``, ``CALL LBL ... REP``, ``CALL PGM``), Q parameters (``FN 0`` to ``FN 12``, formula
lines), drilling cycles 200, 201, 203 and 205 at ``CYCL CALL``, ``CYCL CALL PAT``,
``CYCL CALL POS``, ``M99`` and ``M89``, datum shift (cycle 7), ``STOP`` and M functions.
The facts are in docs/check.md#klartext.
"""

from __future__ import annotations

import math
import re
import time
from array import array
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace
from typing import ClassVar

from opendnc.errors import InputError
from opendnc.nccheck import codes
from opendnc.nccheck.api import Budget, Library
from opendnc.nccheck.limits import MachineLimits
from opendnc.nccheck.path import (
    RAPID_MM_PER_MIN,
    Toolpath,
    radius_arc_center,
    rapid_rate,
    short_radius,
)
from opendnc.nccheck.result import (
    MAX_PROBLEMS,
    CheckResult,
    Control,
    EndState,
    Plane,
    Problem,
    Severity,
    Stock,
    Units,
)
from opendnc.nccheck.source import Source, TextSource


class FormulaError(InputError):
    """A Q-parameter formula that cannot be read (reported as a problem, never raised out)."""


__all__ = ["run_klartext"]

_NUMBERED = re.compile(r"^\s*(\d+)\s*(.*)$")
# possessive blanks (\s*+): two blank runs side by side (around an optional sign or "=")
# would otherwise be split every way on a long run of blanks, quadratic on user text
_VALUE = r"([+-]?)\s*+(QL\d+|QR\d+|Q\d+|\d+(?:\.\d*)?|\.\d+)"
_AXIS_WORD = re.compile(r"\b(I?)([XYZABCUVW])\s*+" + _VALUE)
_POLAR = re.compile(r"\b(I?)(PR|PA)\s*+" + _VALUE)
_WORD = re.compile(r"\b(F|S|R|DL|DR2|DR|M|REP|L)\s*+" + _VALUE)
# a straight move with absolute literal X/Y/Z only, and at most R0 and F: see _plain_line
# at most 15 digits a part: a longer number takes the general path, which reports one that
# overflows (a float of 309 digits is inf, which no move or JSON answer may carry)
_PLAIN_L = re.compile(
    r"L((?: +[XYZ][+-]?\d{1,15}(?:\.\d{0,15})?)+)(?: +R0)?(?: +F(\d{1,15}(?:\.\d{0,15})?))? *"
)
# the same in the order posts write (X, Y, Z once each): one match gives the axes' numbers
_NUMBER15 = r"\d{1,15}(?:\.\d{0,15})?"
_L_XYZ = (
    rf"L(?= +[XYZ])(?: +X([+-]?{_NUMBER15}))?(?: +Y([+-]?{_NUMBER15}))?"
    rf"(?: +Z([+-]?{_NUMBER15}))?(?: +R0)?(?: +F({_NUMBER15}))?"
)
_PLAIN_XYZ = re.compile(_L_XYZ + " *")
# a whole line "12 L X+1 Y-2 Z-0.5 F800" as posts write them (upper case, no comment, no "~",
# no comma, nothing to skip): _read takes its number, text and numbers from one match
_PLAIN_LINE = re.compile(rf"[ \t]*([0-9]+) +({_L_XYZ}) *")
_WORD_START = re.compile(r"\b(?:F|S|R|DL|DR|M|REP|L)\s*[+\-.\dQ]")  # any word at all
_Q_PARAM = re.compile(r"^(Q|QL|QR)(\d+)$")
# a cycle parameter is a number, a Q parameter or one of the words the TNC offers in its
# place (Q206 = AUTO / FAUTO / FMAX, PREDEF for a GLOBAL DEF value): docs/check.md#cycles
_CYCLE_PARAM = re.compile(r"\b(Q\d++)\s*+=\s*+(?:" + _VALUE + r"|(AUTO|FAUTO|FMAX|FU|FZ|PREDEF)\b)")
_STRING = re.compile(r'"([^"]*)"')
_TOL_MM = 0.01
_DRILLING = (200, 201, 203, 205)
# cycles that take effect where they are defined and are not called (docs/check.md#cycles):
# defining one leaves the cycle a CYCL CALL or M99 runs unchanged
_DEF_ACTIVE = frozenset({7, 8, 9, 10, 11, 13, 14, 19, 26, 32, 247})
_CALL_NEST = 20
# the working plane's two axes by tool axis (index 0, 1, 2 = X, Y, Z)
_PLANES = ((1, 2, Plane.YZ), (2, 0, Plane.ZX), (0, 1, Plane.XY))
# lines without a block number that belong to the CYCL DEF / PATTERN DEF before them
_PARAM_LINE = re.compile(r"^(Q\d+\s*=|POS\d|POINT|ROW|PAT|FRAME|CIRC|PITCH|\))")
# a digit, a comma, a digit: a decimal comma, which the TNC does not read (docs/check.md)
_DECIMAL_COMMA = re.compile(r"(\d),(\d)")
# the whole number that holds the comma, for the message; the lookbehind starts the search at
# the start of a number only, so a long digit run is scanned once, not once a digit
_COMMA_NUMBER = re.compile(r"(?<![\d.])[\d.]*\d,\d[\d.]*")
# an FN function head in any spacing: "FN 18: ", "FN18:", "FN18:SYSREAD" (what posts write)
_FN_HEAD = re.compile(r"^FN\s*(\d+)\s*:\s*")
_TEXT_HEADS = (
    "QS", "FN 15", "FN 16", "FN 27", "FN 28", "FN 30", "FN 31", "FN15", "FN16", "FN27", "FN28",
    "FN30", "FN31", "*", "CALL PGM", "SEL ",
)  # fmt: skip
_SPINDLE_START = re.compile(r"\bM(3|4|13|14)\b")
_PRESET_Q = range(100, 200)  # Q100-Q199: set by the TNC itself (tool radius, results)


def _literal(token: str) -> float:
    """A number written in the program; one too large for a float is an error of its block
    (``float`` would give inf, which no move, time or JSON answer may carry)."""
    value = float(token)
    if not math.isfinite(value):
        raise FormulaError(f"the number {token[:12]}... is out of range")
    return value


class _Stop(Exception):
    """The run ends here."""


@dataclass(slots=True)
class _Line:
    # made only for a block that reports or is more than a plain straight move
    line: int
    block: int | None
    text: str  # upper case, comment removed
    raw: str  # the line as written, kept only where case matters (TOOL CALL, CALL PGM)
    params: tuple[str, ...] | list[str] = ()  # continuation lines (cycle parameters)
    note: str | None = None  # a problem found while reading the line


_Axes = tuple[str | None, str | None, str | None, str | None]
_CHUNK = 256  # blocks a piece (a power of two: index >> 8 is the piece)
_SHIFT = 8
_CACHED = 64  # pieces kept parsed (about 16,000 blocks) for loops and label calls
_PENDING = 256  # calls to labels not yet read kept to report (the rest only counted)


class _Piece:
    """Up to 256 consecutive blocks of a program in parallel lists; a :class:`_Line` is
    made on demand (the rare parts, a case-kept raw line, cycle parameters, a reading
    problem, sit in dictionaries by index)."""

    __slots__ = ("axes", "blocks", "lines", "notes", "params", "raw", "texts")

    def __init__(self) -> None:
        self.texts: list[str] = []
        self.lines: list[int] = []  # file lines
        self.blocks: list[int | None] = []  # block numbers (None: a block without one)
        self.axes: list[_Axes | None] = []  # a plain L line's numbers, as _read took them
        self.raw: dict[int, str] = {}
        self.params: dict[int, list[str]] = {}
        self.notes: dict[int, str] = {}

    def item(self, index: int) -> _Line:
        """Block ``index`` of the piece as a line record."""
        return _Line(
            self.lines[index],
            self.blocks[index],
            self.texts[index],
            self.raw.get(index, ""),
            self.params.get(index, ()),
            self.notes.get(index),
        )

    def add(
        self,
        line: int,
        block: int | None,
        text: str,
        raw: str,
        params: list[str] | None,
        note: str | None,
        axes: _Axes | None,
    ) -> None:
        index = len(self.texts)
        self.texts.append(text)
        self.lines.append(line)
        self.blocks.append(block)
        self.axes.append(axes)
        if raw or params or note:
            self.extras(index, raw, params, note)

    def extras(self, index: int, raw: str, params: list[str] | None, note: str | None) -> None:
        """The rare parts of block ``index``."""
        if raw:
            self.raw[index] = raw
        if params:
            self.params[index] = params
        if note:
            self.notes[index] = note


# one block as read: file line, offset of that line, block number, text, case-kept text,
# continuation lines, a problem found while reading it, and for a line _PLAIN_LINE matched
# its numbers of X, Y, Z and F as written (None: not in the block)
_Read = tuple[int, int, int | None, str, str, list[str] | None, str | None, _Axes | None]


def _read(source: Source, offset: int = 0, line: int = 1) -> Iterator[_Read]:
    """The blocks of ``source`` from ``offset`` (the start of a block's first line ``line``),
    each with its continuation lines (``~`` at the end of a line, cycle parameters after a
    ``CYCL DEF`` or ``PATTERN DEF`` without block numbers). Yields a block once the next
    one starts, so its parameters are all there."""
    pending: tuple[int, int, int | None, str, str] | None = None
    params: list[str] | None = None
    note_held: str | None = None
    axes_held: _Axes | None = None
    continuing = False  # the line before ended in "~"
    defines = False  # the last block is a CYCL DEF / PATTERN DEF (parameters may follow)
    numbered = _NUMBERED.match
    plain = _PLAIN_LINE.fullmatch
    for number, start, raw in source.lines(offset, line):
        if not continuing and (match := plain(raw)) is not None:
            # what the steps below make of such a line, with its numbers already split off
            digits, body, x, y, z, feed = match.groups()
            if pending is not None:
                yield (*pending, params, note_held, axes_held)
            pending = (number, start, int(digits), body, "")
            params, note_held, axes_held = None, None, (x, y, z, feed)
            defines = False
            continue
        code = raw.partition(";")[0].strip()
        if not code:
            continue
        upper = code.upper()
        if upper[0] == "/":  # a skippable block "/ 11 STOP": run as with skip off
            upper = upper[1:].lstrip()
        note = None
        if "," in upper and not upper.lstrip("0123456789 ").startswith(_TEXT_HEADS):
            upper, note = _decimal_comma(upper)
        # "~" continues a block on the next line; it may stand after a ";" comment
        tilde = "~" in raw and raw.rstrip().endswith("~")
        if upper.endswith("~"):
            upper = upper.rstrip("~").strip()
        head, _, rest = upper.partition(" ")
        if head.isdecimal():  # "12 L X+1" (most lines): what _NUMBERED gives, without it
            parts: tuple[str, str] | None = (head, rest.lstrip())
        else:
            match = numbered(upper)
            parts = None if match is None else (match.group(1), match.group(2))
        if pending is not None and (
            continuing or (parts is None and defines and _PARAM_LINE.match(upper))
        ):
            if defines:
                if params is None:
                    params = []
                params.append(upper)
            else:  # "Q2 = COS ( ... ) + ( 5 * ~" goes on: one formula over two lines
                pending = (*pending[:3], f"{pending[3]} {upper}", pending[4])
                axes_held = None  # its text goes on: the numbers of its first line are not all
            if note and note_held is None:
                note_held = note
            continuing = tilde
            continue
        continuing = tilde
        if parts is None:  # a block without a number: run it all the same
            block = None
            body = upper
        else:
            body = parts[1]
            if body[-1:] == "~":
                body = body.rstrip("~").strip()
            if body[:1] == "/":
                body = body[1:].lstrip()
            if not body:  # "3 ; T1 D=12": a numbered comment block
                continue
            block = int(parts[0])
        if body[:2] == "FN":  # "FN18:SYSREAD", as posts write it, is "FN 18: SYSREAD"
            body = _FN_HEAD.sub(r"FN \1: ", body, count=1)
        if pending is not None:
            yield (*pending, params, note_held, axes_held)
        pending = (number, start, block, body, raw if body.startswith(_CASE_KEPT) else "")
        params, note_held, axes_held = None, note, None
        defines = body.startswith(("CYCL DEF", "PATTERN DEF"))
    if pending is not None:
        yield (*pending, params, note_held, axes_held)


@dataclass
class _Program:
    """A program read as the run needs it: its blocks are read in pieces of 256 as the run
    (or a look-ahead for a label) reaches them and forgotten again; what stays is where each
    piece starts in the file (to read it again on a jump back) and the labels."""

    name: str
    source: Source
    external: bool = False
    count: int = 0  # blocks read so far
    closed: int = 0  # pieces complete (the run may use them)
    complete: bool = False  # the scan has passed the last block
    offsets: array[int] = field(default_factory=lambda: array("q"))  # piece -> file offset
    starts: array[int] = field(default_factory=lambda: array("q"))  # piece -> file line
    labels: dict[str, int] = field(default_factory=dict)  # label -> block index
    first: _Line | None = None  # the first block
    last: _Line | None = None  # the last block (once complete)
    end: _Line | None = None  # the first END PGM block
    # calls and jumps to labels not read yet: errors when the end comes without them
    pending: dict[str, list[_Line]] = field(default_factory=dict)
    pending_more: dict[str, int] = field(default_factory=dict)  # past _PENDING: counted
    scan: Iterator[bool] | None = None


@dataclass
class _Frame:
    program: _Program
    pc: int
    kind: str  # main, lbl, pgm
    call_line: int
    label: str = ""


class _Expr:
    """A tiny Q-parameter formula evaluator (``Q1 = Q2 * 3 + SIN Q3``, ``FN 4: ... DIV ...``)."""

    _TOKEN = re.compile(r"\s*(QL\d+|QR\d+|Q\d+|\d+(?:\.\d*)?(?:E[+-]?\d+)?|\.\d+|[A-Z]+|\S)")
    _FUNCTIONS: ClassVar[dict[str, Callable[[float], float]]] = {
        "SIN": lambda x: math.sin(math.radians(x)),
        "COS": lambda x: math.cos(math.radians(x)),
        "TAN": lambda x: math.tan(math.radians(x)),
        "ASIN": lambda x: math.degrees(math.asin(x)),
        "ACOS": lambda x: math.degrees(math.acos(x)),
        "ATAN": lambda x: math.degrees(math.atan(x)),
        "SQRT": math.sqrt,
        "SQ": lambda x: x * x,
        "ABS": abs,
        "INT": lambda x: float(math.trunc(x)),
        "FRAC": lambda x: x - math.trunc(x),
        "SGN": lambda x: float((x > 0) - (x < 0)),
        "NEG": lambda x: -x,
        "LN": math.log,
        "LOG": math.log10,
        "EXP": math.exp,
    }

    def __init__(self, text: str, lookup: Callable[[str], float]) -> None:
        self.tokens = [t for t in self._TOKEN.findall(text) if t]
        self.pos = 0
        self.lookup = lookup

    def peek(self) -> str | None:
        return self.tokens[self.pos] if self.pos < len(self.tokens) else None

    def take(self) -> str:
        token = self.peek()
        if token is None:
            raise FormulaError("the formula ends early")
        self.pos += 1
        return token

    def value(self) -> float:
        result = self.sum()
        if self.peek() is not None:
            raise FormulaError(f"unexpected {self.peek()!r} in the formula")
        if not math.isfinite(result):
            raise FormulaError("the formula overflowed")
        return result

    def sum(self) -> float:
        left = self.product()
        while self.peek() in ("+", "-", "LEN", "ANG"):
            op = self.take()
            right = self.product()
            if op == "+":
                left += right
            elif op == "-":
                left -= right
            elif op == "LEN":  # FN 8: length of the vector (left, right)
                left = math.hypot(left, right)
            else:  # FN 13: angle of the vector (left, right) from +X, in degrees
                left = math.degrees(math.atan2(right, left))
        return left

    def product(self) -> float:
        left = self.power()
        while self.peek() in ("*", "/", "DIV"):
            op = self.take()
            right = self.power()
            if op == "*":
                left *= right
            elif right == 0:
                raise ZeroDivisionError
            else:
                left /= right
        return left

    def power(self) -> float:
        base = self.unary()
        if self.peek() == "^":
            self.take()
            return math.pow(base, self.power())  # ValueError / OverflowError, never complex
        return base

    def unary(self) -> float:
        token = self.peek()
        if token in ("+", "-"):
            self.take()
            operand = self.unary()
            return -operand if token == "-" else operand
        return self.primary()

    def primary(self) -> float:
        token = self.take()
        if token == "(":
            inner = self.sum()
            if self.take() != ")":
                raise FormulaError("a formula bracket is not closed")
            return inner
        if token == "PI":
            return math.pi
        if token in self._FUNCTIONS:
            return float(self._FUNCTIONS[token](self.unary()))
        if _Q_PARAM.match(token):
            return self.lookup(token)
        if token[0].isdigit() or token[0] == ".":
            return _literal(token)
        raise FormulaError(f"unexpected {token!r} in the formula")


class _Run:
    def __init__(
        self,
        source: Source,
        name: str,
        machine: MachineLimits | None,
        library: Library | None,
        budget: Budget,
    ) -> None:
        self.name = name
        self.machine = machine
        self.library = library
        self.budget = budget
        self.problems: dict[tuple[int, str], Problem] = {}
        self.more_problems = 0
        self.more_errors = 0
        self.unset_reads: set[str] = set()
        self.pending_unset: list[str] = []  # read before set, reported at the block's end
        self.cycle_words: dict[str, str] = {}  # Q206 -> "AUTO" of the cycle in force
        travel = dict(machine.travel) if machine and machine.travel else None
        rapid = (machine.rapid_rate if machine else None) or RAPID_MM_PER_MIN
        self.path = Toolpath(max_moves=budget.moves, rapid_rate=rapid, travel=travel)
        self.preset: tuple[float | None, float | None, float | None] = (None, None, None)
        if machine is not None and "G54" in machine.work_offsets:
            axes = machine.work_offsets["G54"]
            self.preset = (axes.get("X"), axes.get("Y"), axes.get("Z"))
        self.frames: list[_Frame] = []
        self.called: dict[str, _Program | None] = {}  # CALL PGM name -> program (asked once)
        self.q: dict[str, float] = {}
        self.units: Units | None = None
        self.stock_min: list[float] | None = None
        self.stock: Stock | None = None
        self.stock_axis = "Z"
        self.pos: list[float | None] = [None, None, None]
        self.center: tuple[float, float] | None = None
        self._last_dir: tuple[float, float] | None = None
        self._dir_step: tuple[float, float] | None = None  # a plain line's, made a unit late
        self.shift = [0.0, 0.0, 0.0]
        self.axis = 2  # tool axis: Z
        self.feed: float | None = None
        self.tool_feed: float | None = None
        self.speed = 0.0
        self.spindle_on = False
        self.tool: str | None = None
        self.cycle: tuple[int, dict[str, float], int] | None = None  # number, params, line
        self.m89 = False
        self.pattern: list[tuple[float | None, float | None, float | None]] = []
        self.repeats: dict[tuple[int, int], int] = {}
        self.jumps: dict[int, int] = {}
        self.warned: set[str] = set()
        self.no_feed = False
        self.corner: tuple[str, float, _Line] | None = None  # RND/CHF for the next corner
        self.blocks_run = 0
        self.end_line: _Line | None = None
        self.ended = False
        self.begin: tuple[str, str] | None = None
        self.cache: dict[tuple[int, int], _Piece] = {}  # (program, piece) -> its blocks
        self.scanned = 0  # blocks read (each once: a loop's passes are not)
        self.jump_items: dict[int, _Line] = {}  # line -> its block, for the endless report
        self.main = self._program(source, name)

    @property
    def last_dir(self) -> tuple[float, float] | None:
        """The unit direction at the end of the last contour element in the working plane."""
        step = self._dir_step
        if step is not None:
            length = math.hypot(step[0], step[1])
            self._last_dir = (step[0] / length, step[1] / length)
            self._dir_step = None
        return self._last_dir

    @last_dir.setter
    def last_dir(self, direction: tuple[float, float] | None) -> None:
        self._last_dir = direction
        self._dir_step = None

    # ------------------------------------------------------------------ reporting
    def report(self, where: _Line, severity: Severity, message: str) -> None:
        line, block = where.line, where.block
        frame = self.frames[-1] if self.frames else None
        if frame is not None and frame.program.external:
            message = f"in {frame.program.name} line {line}: {message}"
            line, block = frame.call_line, None
        self._keep(Problem(line, severity, message, block))

    def _keep(self, problem: Problem) -> None:
        """List ``problem`` once; past :data:`MAX_PROBLEMS` only count it (bounded memory)."""
        key = (problem.line, problem.message)
        if key in self.problems:
            return
        if len(self.problems) < MAX_PROBLEMS:
            self.problems[key] = problem
            return
        self.more_problems += 1
        self.more_errors += problem.severity is Severity.ERROR

    def error(self, where: _Line, message: str) -> None:
        self.report(where, Severity.ERROR, message)

    def warn_once(self, where: _Line, key: str, message: str) -> None:
        if key not in self.warned:
            self.warned.add(key)
            self.report(where, Severity.WARNING, message)

    # ------------------------------------------------------------------ reading
    def _program(self, source: Source, name: str, external: bool = False) -> _Program:
        program = _Program(name, source, external)
        program.scan = self._scanner(program)
        return program

    def _scanner(self, program: _Program) -> Iterator[bool]:
        """Read ``program`` in order: check every block once (also those the run never
        reaches), note its labels and its END PGM, and close a piece every 256 blocks
        (yields then)."""
        piece = _Piece()
        texts, lines, blocks, moves = piece.texts, piece.lines, piece.blocks, piece.axes
        index = 0
        for line, offset, block, text, raw, params, note, axes in _read(program.source):
            at = index & (_CHUNK - 1)
            if not at:
                program.offsets.append(offset)
                program.starts.append(line)
            texts.append(text)
            lines.append(line)
            blocks.append(block)
            moves.append(axes)
            if raw or params or note:
                piece.extras(at, raw, params, note)
            if not index:
                program.first = piece.item(0)
            # a straight move without M functions has a known head and nothing to check
            message = None if text[:2] == "L " and "M" not in text else _static_problem(text)
            if message or note:
                item = piece.item(at)
                if note:
                    self._static(program, item, note)
                if message:
                    self._static(program, item, message)
            if "LBL" in text:
                self._scan_label(program, piece, index)
            if program.end is None and text.startswith("END PGM"):
                program.end = piece.item(at)
            index += 1
            program.count = index
            self.scanned += 1
            if not index & (_CHUNK - 1):
                self._cache_piece(program, (index >> _SHIFT) - 1, piece)
                program.closed = index >> _SHIFT
                program.last = piece.item(_CHUNK - 1)
                piece = _Piece()
                texts, lines, blocks, moves = piece.texts, piece.lines, piece.blocks, piece.axes
                yield True
        if piece.texts:
            self._cache_piece(program, index >> _SHIFT, piece)
            program.closed += 1
            program.last = piece.item(len(piece.texts) - 1)
        program.complete = True
        self._close(program)

    def _scan_label(self, program: _Program, piece: _Piece, index: int) -> None:
        """A label read (defined twice is an error), or a call of or jump to one (kept until
        its label is read: an error when the program ends without it)."""
        at = index & (_CHUNK - 1)
        text = piece.texts[at]
        if text.startswith("LBL"):
            label = _label(text[3:])
            if label in program.labels and label != "0":
                self._static(program, piece.item(at), f"label {label} is defined twice")
            program.labels.setdefault(label, index)
            program.pending.pop(label, None)
            program.pending_more.pop(label, None)
            return
        target = None
        if text.startswith("CALL LBL"):
            target = _label(text[8:].split(" REP")[0])
        elif "GOTO LBL" in text:
            target = _label(text.split("GOTO LBL", 1)[1])
        if target is None or target in program.labels:
            return
        if sum(map(len, program.pending.values())) < _PENDING:
            program.pending.setdefault(target, []).append(piece.item(at))
        else:
            program.pending_more[target] = program.pending_more.get(target, 0) + 1

    def _close(self, program: _Program) -> None:
        """The scan has passed the last block: calls of labels it never read are errors."""
        for label, items in program.pending.items():
            for item in items:
                self._static(program, item, f"label {label} is not defined")
        if not program.external:
            more = sum(program.pending_more.values())
            self.more_problems += more
            self.more_errors += more
        program.pending = {}
        program.pending_more = {}

    def _cache_piece(self, program: _Program, index: int, piece: _Piece) -> None:
        cache = self.cache
        if len(cache) >= _CACHED:
            del cache[next(iter(cache))]  # the oldest piece goes
        cache[(id(program), index)] = piece

    def _step(self, program: _Program) -> bool:
        """Read one more piece of ``program``; False at its end."""
        if program.complete or program.scan is None:
            return False
        if not next(program.scan, False):
            program.complete = True
            return False
        return True

    def _piece(self, program: _Program, index: int) -> _Piece | None:
        """Piece ``index`` of ``program`` (read on to it, or again from the file); None past
        the program's end."""
        while index >= program.closed:
            if not self._step(program) and index >= program.closed:
                return None
        piece = self.cache.get((id(program), index))
        if piece is None:
            piece = _Piece()
            start, line = program.offsets[index], program.starts[index]
            for number, _, block, text, raw, params, note, axes in _read(
                program.source, start, line
            ):
                piece.add(number, block, text, raw, params, note, axes)
                if len(piece.texts) == _CHUNK:
                    break
            self._cache_piece(program, index, piece)
        return piece

    def _label_index(self, program: _Program, label: str) -> int | None:
        """The block index of ``label`` in ``program`` (read on to find it)."""
        found = program.labels.get(label)
        while found is None and self._step(program):
            found = program.labels.get(label)
        return found

    def _finish(self, program: _Program) -> None:
        """Read the rest of ``program``: every block is checked, run or not."""
        while self._step(program):
            pass

    def _static(self, program: _Program, where: _Line, message: str) -> None:
        if program.external:
            return  # reported through the call
        self._keep(Problem(where.line, Severity.ERROR, message, where.block))

    # ------------------------------------------------------------------ values
    def q_value(self, name: str) -> float:
        value = self.q.get(name)
        if value is not None:
            return value
        if name not in self.unset_reads and not name.startswith("QR"):
            number = int(name.lstrip("QLR"))
            if name.startswith("QL") or number not in _PRESET_Q:
                self.unset_reads.add(name)
                self.pending_unset.append(name)
        return 0.0

    def number(self, sign: str, token: str) -> float:
        value = self.q_value(token) if token.startswith("Q") else _literal(token)
        return -value if sign == "-" else value

    def formula(self, text: str) -> float:
        return _Expr(text, self.q_value).value()

    # ------------------------------------------------------------------ run
    def run(self) -> None:
        # CPU time of this thread: a busy machine must not turn a long program into a "loop"
        seconds = self.budget.seconds
        deadline = math.inf if seconds is None else time.thread_time() + seconds
        # the block budget is for loops: each block of the file runs once outside it
        limit = self.budget.blocks
        main = self.main
        frames = self.frames
        frames.append(_Frame(main, 0, "main", 0))
        first = self._piece(main, 0)
        if first is None or not first.texts[0].startswith("BEGIN PGM"):
            first_line = main.first or _Line(1, None, "", "")
            self.error(first_line, "the program does not start with BEGIN PGM")
        plain_line = self._plain_line
        try:
            while True:
                frame = frames[-1]
                pc = frame.pc
                piece = self._piece(frame.program, pc >> _SHIFT)
                at = pc & (_CHUNK - 1)
                if piece is None or at >= len(piece.texts):  # past the last block
                    self._fall_off(frame)
                    continue
                texts, moves = piece.texts, piece.axes
                base = pc - at
                # the blocks of this piece in order, until a jump, a call or a return
                while at < len(texts):
                    text = texts[at]
                    frame.pc = pc = base + at + 1
                    self.blocks_run += 1
                    if self.blocks_run & 1023 == 0 and (
                        self.blocks_run - self.scanned >= limit or time.thread_time() > deadline
                    ):
                        self._endless(
                            piece.item(at), out_of_time=self.blocks_run - self.scanned < limit
                        )
                    if text[:2] == "L " and self.corner is None and not self.m89:
                        # the bulk of a posted program: no line record unless it reports
                        axes = moves[at]
                        if axes is None:  # not taken apart as it was read: the text then
                            axes = _plain_axes(text)
                        if axes is not None:
                            plain_line(piece, at, axes)
                            at += 1
                            continue
                    item = piece.item(at)
                    # an error ends its block only: the run goes on, so one problem never
                    # hides the ones after it (the block's effect is left out)
                    try:
                        self._execute(item, frame)
                    except ZeroDivisionError:
                        self.error(item, "division by zero")
                    except RecursionError:
                        self.error(item, "a formula nested too deeply")
                    except (FormulaError, ValueError, OverflowError) as exc:
                        self.error(item, str(exc) or "a value is out of range")
                    if self.pending_unset:
                        self._unset_read(item)
                    if frame.pc != pc or frames[-1] is not frame:
                        break  # a jump, a call or a return: the next block is elsewhere
                    at += 1
        except _Stop:
            pass
        self._finish(main)  # the blocks the run never reached are checked too
        if self.end_line is None and main.count and self.begin is not None:
            # the run stopped (M30, an error): END PGM is still needed in the file
            if main.end is not None:
                self._check_end(main.end)
            else:
                self.error(main.last or _Line(1, None, "", ""), "the program has no END PGM")

    def _unset_read(self, item: _Line) -> None:
        for name in self.pending_unset:
            self.report(
                item,
                Severity.WARNING,
                f"{name} is read before the program sets it: the TNC takes the value an "
                "earlier program left (the dry run takes 0)",
            )
        self.pending_unset.clear()

    def _fall_off(self, frame: _Frame) -> None:
        last = frame.program.last or _Line(1, None, "", "")
        if frame.kind == "main":
            self.error(last, "the program has no END PGM")
            raise _Stop
        self.frames.pop()

    def _endless(self, item: _Line, *, out_of_time: bool) -> None:
        self.frames[1:] = []
        if not self.jumps:
            # no jump back: a long program, not a loop; what follows is not checked, and
            # an unchecked program must not pass (an error, never a silent exit 0)
            blocks = f"{self.blocks_run:,} blocks"
            spent = f"{self.budget.seconds:g} s of CPU" if out_of_time else blocks
            self.error(
                item,
                f"the dry run stopped here after {self.blocks_run:,} blocks (its budget of "
                f"{spent} ran out); the rest of the program is not checked",
            )
            raise _Stop
        where, count = max(self.jumps.items(), key=lambda kv: kv[1])
        target = self.jump_items.get(where, item)
        self.error(
            target,
            f"endless loop: the jump back at line {where} ran {count:,} times; the dry run "
            f"stopped after {self.blocks_run:,} blocks",
        )
        raise _Stop

    def _execute(self, item: _Line, frame: _Frame) -> None:
        text = item.text
        head = text.split(" ", 1)[0] if text else ""
        if "M" in text and (head in _M_HEADS or head == "CYCL") and _SPINDLE_START.search(text):
            # M3/M4/M13/M14 act at the start of their block, before its move (TNC)
            self.spindle_on = True
        if head in ("L", "LN"):
            self._linear(item, text[len(head) :])
        elif head in ("APPR", "DEP"):
            # approach / departure contours: drawn as a straight move to their end point
            self.warn_once(item, head, f"{head} is drawn as a straight move by the dry run")
            self._linear(item, text[len(head) :].lstrip().partition(" ")[2])
        elif head in ("C", "CR", "CT", "CP"):
            self._circle(item, head, text[len(head) :])
            if "M" in text:
                self._m_functions(item, text)
        elif head == "LP":
            self._polar_line(item, text[2:])
        elif head == "CC":
            self._centre(item, text[2:])
        elif head in ("RND", "CHF"):
            self._corner(item, head, text[len(head) :])
        elif text.startswith("BEGIN PGM"):
            self._begin(item)
        elif text.startswith("END PGM"):
            if frame.kind == "main":
                self._check_end(item)
                self.ended = True
                raise _Stop
            self.frames.pop()
        elif text.startswith("BLK FORM"):
            self._blk_form(item)
        elif text.startswith("TOOL CALL"):
            self._tool_call(item)
        elif text.startswith("TOOL DEF"):
            pass
        elif text.startswith("LBL"):
            if _label(text[3:]) == "0" and frame.kind == "lbl":
                self.frames.pop()
        elif text.startswith("CALL LBL"):
            self._call_label(item, frame, text[8:])
        elif text.startswith("CALL PGM"):
            self._call_program(item, text[8:].strip())
        elif text.startswith("FN"):
            self._fn(item, frame)
        elif re.match(r"^QS\d+\s*=", text) or text.startswith("CALL SELECTED"):
            self.warn_once(item, text[:4], f"{text.split('=')[0].strip()[:20]} is not simulated")
        elif re.match(r"^(Q|QL|QR)\d+\s*=", text):
            target, formula = text.split("=", 1)
            self.q[target.strip()] = self.formula(formula)
        elif text.startswith("CYCL DEF"):
            self._cycle_def(item)
        elif text.startswith("CYCL CALL"):
            self._cycle_call(item, text[9:].strip())
        elif text.startswith("PATTERN DEF"):
            self._pattern(item)
        elif text.startswith("STOP") or text.startswith("M"):
            self._m_functions(item, text)
        elif text.startswith("*"):
            pass  # a structure block (section title)
        elif text.startswith(("PLANE", "FUNCTION", "TCH PROBE", "SEL ", "DECLARE")):
            self.warn_once(item, head, f"{head} blocks are not simulated by the dry run")
        else:
            self.error(item, f"unknown block {text.split(' ')[0]!r}")

    # ------------------------------------------------------------------ program frame
    def _begin(self, item: _Line) -> None:
        parts = item.text.split()
        if len(parts) < 4 or parts[3] not in ("MM", "INCH"):
            self.error(item, "BEGIN PGM needs a name and MM or INCH")
            return
        self.begin = (parts[2], parts[3])
        self.units = Units.MM if parts[3] == "MM" else Units.INCH
        if not (self.machine and self.machine.rapid_rate):
            self.path.rapid_rate = rapid_rate(self.units)
        machine = self.machine
        if machine is not None and machine.travel_units not in (None, self.units):
            # travel and preset in the machine's units -> the program's
            factor = 25.4 if self.units is Units.MM else 1 / 25.4
            self.path.scale_travel(factor)
            self.preset = (
                None if self.preset[0] is None else self.preset[0] * factor,
                None if self.preset[1] is None else self.preset[1] * factor,
                None if self.preset[2] is None else self.preset[2] * factor,
            )

    def _check_end(self, item: _Line) -> None:
        self.end_line = item
        parts = item.text.split()
        if self.begin is None:
            return
        name, units = self.begin
        got_name = parts[2] if len(parts) > 2 else ""
        got_units = parts[3] if len(parts) > 3 else ""
        if got_name != name:
            self.error(item, f"END PGM {got_name or '(no name)'} does not match BEGIN PGM {name}")
        if got_units != units:
            self.error(item, f"END PGM units {got_units or '(none)'} differ from BEGIN PGM {units}")

    def _blk_form(self, item: _Line) -> None:
        form = re.match(r"^BLK FORM\s+0\.([12])(?!\d)\s*(.*)$", item.text)
        if form is None:
            return  # BLK FORM CYLINDER, ROTATION...: no box to draw
        kind, rest = form.groups()
        axis = re.match(r"^([XYZ])(?:\s+|$)", rest)  # 0.1 names the tool axis first
        if kind == "1" and axis:
            self.stock_axis = axis.group(1)
            rest = rest[axis.end() :]
        values = {a: v for inc, a, v in self._axes(rest) if not inc}
        incremental = {a: v for inc, a, v in self._axes(rest) if inc}
        if kind == "1":
            self.stock_min = [values.get(a, 0.0) for a in "XYZ"]
        else:
            if self.stock_min is None:
                self.error(item, "BLK FORM 0.2 without BLK FORM 0.1")
                return
            high = [
                values.get(a, self.stock_min[i] + incremental.get(a, 0.0))
                for i, a in enumerate("XYZ")
            ]
            low = self.stock_min
            if any(h <= lo for h, lo in zip(high, low, strict=True)):
                self.error(item, "BLK FORM: the MAX point must be above the MIN point")
                return
            self.stock = Stock(
                (low[0], low[1], low[2]), (high[0], high[1], high[2]), self.stock_axis
            )

    def _axes(self, text: str) -> list[tuple[bool, str, float]]:
        out = []
        for inc, axis, sign, token in _AXIS_WORD.findall(text):
            # a literal number without a call (the bulk of every program runs here)
            value = self.q_value(token) if token[0] == "Q" else _literal(token)
            out.append((inc == "I", axis, -value if sign == "-" else value))
        return out

    def _words(self, text: str) -> dict[str, float]:
        if not _WORD_START.search(text):
            return {}
        return {key: self.number(sign, token) for key, sign, token in _WORD.findall(text)}

    # ------------------------------------------------------------------ tools
    def _tool_call(self, item: _Line) -> None:
        rest = item.text[9:].strip()
        named = _STRING.search(item.raw)
        tool: str | None
        if named:
            tool = named.group(1)
            rest = _STRING.sub("", rest)
        else:
            match = re.match(r"^(Q\d+|\d+)", rest)
            tool = None
            if match:
                token = match.group(1)
                tool = str(round(self.q_value(token))) if token.startswith("Q") else token
                rest = rest[match.end() :]
        axis_match = re.match(r"^\s*([XYZ])\b", rest)
        if axis_match:
            self.axis = "XYZ".index(axis_match.group(1))
        words = self._words(rest)
        if "S" in words:
            self.speed = words["S"]
        if "F" in words:
            self.tool_feed = words["F"]
            if self.feed is None:
                self.feed = words["F"]
        if tool is None:
            return  # a TOOL CALL without a tool changes speed or axis only
        known = self.machine.tools if self.machine is not None else None
        if known is not None and tool not in known:
            name = (self.machine.name if self.machine else "") or "the machine"
            self.error(item, f"tool {tool} is not in the tool table of {name}")
        self.tool = tool
        self.path.change_tool(
            tool,
            item.line,
            axis="XYZ"[self.axis],
            speed=words.get("S"),
            feed=words.get("F"),
            delta_length=words.get("DL"),
            delta_radius=words.get("DR"),
        )

    # ------------------------------------------------------------------ paths
    def _plane(self) -> tuple[int, int, Plane]:
        return _PLANES[self.axis]

    def _feed(self, item: _Line, words: dict[str, float], text: str) -> tuple[bool, float | None]:
        """(rapid, feed) of a path block: FMAX is for its block only, F stays in force."""
        if "FMAX" in text:
            return True, None
        if "FAUTO" in text or "F AUTO" in text:
            return False, self.tool_feed
        if "F" in words:
            self.feed = words["F"]
        return False, self._cutting(item)

    def _cutting(self, item: _Line) -> float | None:
        """The feed in force for a cutting move (an error when none, a warning when the
        spindle is stopped)."""
        if not self.feed and not self.no_feed:
            self.no_feed = True
            self.error(item, "a path with no feed rate (F) in force")
        if not self.spindle_on:
            self.warn_once(item, "spindle", "a cutting move with the spindle stopped")
        return self.feed

    def _target(
        self, text: str, axes: list[tuple[bool, str, float]] | None = None
    ) -> list[float | None]:
        target = self.pos[:]
        for inc, axis, value in self._axes(text) if axes is None else axes:
            index = "XYZ".find(axis)
            if index < 0:
                continue
            if inc:
                current = target[index]
                target[index] = None if current is None else current + value
            else:
                target[index] = value + self.shift[index]
        return target

    def _machine(self, point: list[float | None]) -> list[float | None]:
        return [
            None if v is None or p is None else v + p
            for v, p in zip(point, self.preset, strict=True)
        ]

    def _go(
        self, item: _Line, target: list[float | None], *, rapid: bool, feed: float | None
    ) -> None:
        if self.corner is not None:
            if rapid:
                self.corner = None  # a rounding needs two contour lines
            else:
                self._round_corner(item, target, feed)
        start = self.pos
        self.path.line(
            tuple(start), tuple(target), item.line, rapid=rapid, feed=feed,
            machine_end=self._machine(target) if self.path.check_travel else None,
        )  # fmt: skip
        a, b, _ = self._plane()
        sa, sb, ea, eb = start[a], start[b], target[a], target[b]
        if sa is not None and sb is not None and ea is not None and eb is not None:
            length = math.hypot(ea - sa, eb - sb)
            if length > 1e-9:
                self.last_dir = ((ea - sa) / length, (eb - sb) / length)
        self.pos = target

    def _plain_line(self, piece: _Piece, index: int, axes: _Axes) -> None:
        """``L X.. Y.. Z.. [R0] [F..]`` with absolute literal coordinates, the bulk of a
        posted program: the same as :meth:`_linear` (no RND/CHF pending, no M89) with less
        work per block; the block's line record is made only when it reports. ``axes``:
        the numbers of X, Y, Z and F as written (None: not in the block)."""
        x, y, z, feed = axes
        start = self.pos
        target = start[:]
        shift = self.shift
        if x is not None:
            target[0] = float(x) + shift[0]
        if y is not None:
            target[1] = float(y) + shift[1]
        if z is not None:
            target[2] = float(z) + shift[2]
        if feed is not None:
            self.feed = float(feed)
        if not self.feed or not self.spindle_on:
            item = piece.item(index)
            self._go(item, target, rapid=False, feed=self._cutting(item))
            return
        path = self.path
        path.line(
            start, target, piece.lines[index], rapid=False, feed=self.feed,
            machine_end=self._machine(target) if path.check_travel else None,
        )  # fmt: skip
        a, b, _ = _PLANES[self.axis]  # the direction at the end, as _go keeps it
        sa, sb, ea, eb = start[a], start[b], target[a], target[b]
        if sa is not None and sb is not None and ea is not None and eb is not None:
            da, db = ea - sa, eb - sb
            if da * da + db * db > 1e-18:  # longer than 1e-9: made a unit when asked for
                self._dir_step = (da, db)
        self.pos = target

    def _linear(self, item: _Line, text: str) -> None:
        axes = self._axes(text)
        words = self._words(text)
        has_m = "M" in text
        target = self._target(text, axes)
        if has_m and re.search(r"\bM91\b", text):  # machine coordinates for this block
            for inc, axis, value in axes:
                index = "XYZ".find(axis)
                if index >= 0 and not inc:
                    preset = self.preset[index]
                    target[index] = None if preset is None else value - preset
        moves = any(axis in "XYZ" for _, axis, _ in axes)
        if moves:
            rapid, feed = self._feed(item, words, text) if "FMAX" not in text else (True, None)
            self._go(item, target, rapid=rapid, feed=feed)
        elif "F" in words:
            self.feed = words["F"]
        if has_m:
            self._m_functions(item, text)
        if moves and self.m89 and self.cycle is not None and "M99" not in text:
            self._drill(item)

    def _centre(self, item: _Line, text: str) -> None:
        """CC: the circle centre (pole); without coordinates, the last position."""
        a, b, _ = self._plane()
        axes = [(inc, "XYZ".find(axis), value) for inc, axis, value in self._axes(text)]
        if self.center is not None and axes:
            ca: float | None
            cb: float | None
            ca, cb = self.center
        else:
            ca, cb = self.pos[a], self.pos[b]
        for inc, index, value in axes:
            if index not in (a, b):
                continue
            base = self.pos[index]
            new = (None if base is None else base + value) if inc else value + self.shift[index]
            if index == a:
                ca = new
            else:
                cb = new
        if ca is None or cb is None:
            self.error(item, "CC without a known centre")
            return
        self.center = (ca, cb)

    def _circle(self, item: _Line, kind: str, text: str) -> None:
        self.corner = None  # RND/CHF are drawn between straight lines only
        words = self._words(text)
        _rapid, feed = self._feed(item, words, text)
        a, b, plane = self._plane()
        c = 3 - a - b
        start = self.pos
        if start[a] is None or start[b] is None or start[c] is None:
            self.warn_once(item, "arc-unknown", "an arc from an unknown position is not drawn")
            self.pos = self._target(text)
            return
        sa, sb = float(start[a] or 0.0), float(start[b] or 0.0)
        ccw = "DR+" in text.replace(" ", "")
        cw = "DR-" in text.replace(" ", "")
        if kind == "CP":
            self._polar_arc(item, text, feed, cw=cw, ccw=ccw)
            return
        target = self._target(text)
        end_a, end_b = target[a], target[b]
        ea = end_a if end_a is not None else sa
        eb = end_b if end_b is not None else sb
        tol = _TOL_MM if self.units is not Units.INCH else 0.0005
        if kind == "C":
            if self.center is None:
                self.error(item, "C without a circle centre (CC)")
                return
            if not (cw or ccw):
                self.error(item, "C needs a direction of rotation DR+ or DR-")
                return
            ca, cb = self.center
            r0, r1 = math.hypot(sa - ca, sb - cb), math.hypot(ea - ca, eb - cb)
            if abs(r0 - r1) > tol:
                self.error(
                    item,
                    f"the arc's end is not on its circle: start radius {r0:.4f}, end radius "
                    f"{r1:.4f} (differ by {abs(r0 - r1):.4f})",
                )
                return
            clockwise = cw
        elif kind == "CR":
            radius = words.get("R")
            if radius is None or not (cw or ccw):
                self.error(item, "CR needs a radius R and a direction DR+ or DR-")
                return
            chord = math.hypot(ea - sa, eb - sb)
            if chord < 1e-9:
                self.error(item, "CR with the same start and end point")
                return
            too_small = short_radius(radius, chord, tol)
            if too_small is not None:
                self.error(item, f"radius {too_small}")
                return
            ca, cb = radius_arc_center((sa, sb), (ea, eb), chord, radius, ccw=ccw)
            clockwise = cw
        else:  # CT: tangential to the element before
            if self.last_dir is None:
                self.error(item, "CT needs a contour element before it to be tangent to")
                return
            da, db = ea - sa, eb - sb
            na, nb = -self.last_dir[1], self.last_dir[0]
            dot = da * na + db * nb
            if abs(dot) < 1e-9:
                self._go(item, target, rapid=False, feed=feed)
                return
            s = (da * da + db * db) / (2 * dot)
            ca, cb = sa + na * s, sb + nb * s
            clockwise = s < 0
        self._arc(item, target, (ca, cb), plane, clockwise=clockwise, feed=feed)

    def _arc(
        self,
        item: _Line,
        target: list[float | None],
        centre: tuple[float, float],
        plane: Plane,
        *,
        clockwise: bool,
        feed: float | None,
    ) -> None:
        a, b, _ = self._plane()
        start = tuple(float(v or 0.0) for v in self.pos)
        end = tuple(float(t if t is not None else s) for t, s in zip(target, start, strict=True))
        point = [0.0, 0.0, 0.0]
        point[a], point[b] = centre
        point[3 - a - b] = start[3 - a - b]
        machine = tuple(self._machine([0.0, 0.0, 0.0]))
        self.path.arc(
            (start[0], start[1], start[2]), (end[0], end[1], end[2]),
            (point[0], point[1], point[2]), plane, item.line,
            clockwise=clockwise, feed=feed, machine_shift=machine,
        )  # fmt: skip
        # the direction at the end: perpendicular to the radius
        ra, rb = end[a] - centre[0], end[b] - centre[1]
        length = math.hypot(ra, rb) or 1.0
        self.last_dir = (rb / length, -ra / length) if clockwise else (-rb / length, ra / length)
        self.pos = list(end)

    def _polar(self, text: str) -> tuple[float, float] | None:
        """Radius and angle of an LP end point about the pole (CC is known); None when they
        build on a position the dry run does not know (IPR/IPA, or PR/PA left out)."""
        a, b, _ = self._plane()
        assert self.center is not None
        ca, cb = self.center
        words = _POLAR.findall(text)
        absolute = {key for inc, key, _, _ in words if not inc}
        radius = angle = 0.0
        if absolute != {"PR", "PA"}:  # the end builds on the position: it must be known
            if self.pos[a] is None or self.pos[b] is None:
                return None
            pa, pb = float(self.pos[a] or 0.0), float(self.pos[b] or 0.0)
            radius = math.hypot(pa - ca, pb - cb)
            angle = math.degrees(math.atan2(pb - cb, pa - ca))
        for inc, key, sign, token in words:
            value = self.number(sign, token)
            if key == "PR":
                radius = radius + value if inc else value
            else:
                angle = angle + value if inc else value
        return radius, angle

    def _polar_line(self, item: _Line, text: str) -> None:
        words = self._words(text)
        if self.center is None:
            self.error(item, "LP needs a pole (CC)")
            return
        polar = self._polar(text)
        a, b, _ = self._plane()
        if polar is None:
            # the TNC knows where the tool is (after TOOL CALL it is somewhere); the dry
            # run does not, so this move is not drawn and the position stays unknown
            self.warn_once(item, "lp-unknown", "an LP from an unknown position is not drawn")
            self.pos[a] = self.pos[b] = None
            self._m_functions(item, text)
            return
        radius, angle = polar
        target = self.pos[:]
        target[a] = self.center[0] + radius * math.cos(math.radians(angle))
        target[b] = self.center[1] + radius * math.sin(math.radians(angle))
        for inc, axis, value in self._axes(text):
            index = "XYZ".find(axis)
            if index == 3 - a - b:
                current = target[index]
                target[index] = (None if current is None else current + value) if inc else value
        rapid, feed = self._feed(item, words, text)
        self._go(item, target, rapid=rapid, feed=feed)
        self._m_functions(item, text)

    def _polar_arc(
        self, item: _Line, text: str, feed: float | None, *, cw: bool, ccw: bool
    ) -> None:
        if self.center is None:
            self.error(item, "CP needs a pole (CC)")
            return
        if not (cw or ccw):
            self.error(item, "CP needs a direction of rotation DR+ or DR-")
            return
        a, b, plane = self._plane()
        c = 3 - a - b
        ca, cb = self.center
        pa, pb = float(self.pos[a] or 0.0), float(self.pos[b] or 0.0)
        radius = math.hypot(pa - ca, pb - cb)
        start_angle = math.degrees(math.atan2(pb - cb, pa - ca))
        sweep = 0.0
        for inc, key, sign, token in _POLAR.findall(text):
            value = self.number(sign, token)
            if key == "PA":
                sweep = value if inc else ((value - start_angle) % 360.0 or 360.0)
                if not inc and cw:
                    sweep = -((start_angle - value) % 360.0 or 360.0)
        if sweep == 0:
            self.error(item, "CP without an angle PA or IPA")
            return
        rise = 0.0
        for inc, axis, value in self._axes(text):
            if "XYZ".find(axis) == c:
                rise = value if inc else value - float(self.pos[c] or 0.0)
        turns = max(1, math.ceil(abs(sweep) / 359.0))
        step = sweep / turns
        angle = start_angle
        for _ in range(turns):
            angle += step
            target = self.pos[:]
            target[a] = ca + radius * math.cos(math.radians(angle))
            target[b] = cb + radius * math.sin(math.radians(angle))
            target[c] = float(self.pos[c] or 0.0) + rise / turns
            self._arc(item, target, (ca, cb), plane, clockwise=step < 0, feed=feed)

    def _corner(self, item: _Line, kind: str, text: str) -> None:
        words = self._words(text)
        value = words.get("R") if kind == "RND" else None
        if kind == "CHF":
            match = re.match(r"^\s*([+-]?\d*\.?\d+)", text)
            value = float(match.group(1)) if match else None
        if value is None or value <= 0:
            self.error(item, f"{kind} needs a positive {'radius R' if kind == 'RND' else 'length'}")
            value = None
        elif self.last_dir is None:
            # the TNC rounds the corner between the element before and the one after
            self.error(item, f"{kind} needs a contour element before it")
            value = None
        if "F" in words:
            self.feed = words["F"]
        self.corner = None if value is None else (kind, value, item)

    def _round_corner(self, item: _Line, target: list[float | None], feed: float | None) -> None:
        """RND/CHF pending at the current position, between the last line and one to
        ``target``: trim both lines and put the arc or chamfer between them (line-line
        corners in the working plane; other corners stay sharp)."""
        corner, self.corner = self.corner, None
        if corner is None:
            return
        kind, size, where = corner
        a, b, plane = self._plane()
        c = 3 - a - b
        last = self.path.last  # kept for the preview or not (the command line keeps none)
        here, there = self.pos, target
        if (
            last is None
            or None in here
            or None in there
            or here[c] != there[c]
            or last.start[c] != last.end[c]
            or math.dist(last.end, tuple(float(v or 0.0) for v in here)) > 1e-9
        ):
            return
        p1 = (float(here[a] or 0.0), float(here[b] or 0.0))
        p0 = (last.start[a], last.start[b])
        p2 = (float(there[a] or 0.0), float(there[b] or 0.0))
        back, ahead = math.dist(p1, p0), math.dist(p1, p2)
        if back < 1e-9 or ahead < 1e-9:
            return
        u = ((p0[0] - p1[0]) / back, (p0[1] - p1[1]) / back)
        v = ((p2[0] - p1[0]) / ahead, (p2[1] - p1[1]) / ahead)
        cos = max(-1.0, min(1.0, u[0] * v[0] + u[1] * v[1]))
        theta = math.acos(cos)  # the inner angle of the corner
        if theta < 1e-6 or math.pi - theta < 1e-6:
            return  # no corner (straight on, or back on itself)
        cut = size / math.tan(theta / 2) if kind == "RND" else size
        if cut >= back - 1e-9 or cut >= ahead - 1e-9:
            self.error(where, f"{kind} {size:g} does not fit its corner")
            return
        trimmed = self.path.trim_last_feed(cut)
        if trimmed is None:
            return
        start = [0.0, 0.0, 0.0]
        start[a], start[b], start[c] = p1[0] + v[0] * cut, p1[1] + v[1] * cut, trimmed.end[c]
        self.pos = list(trimmed.end)
        if kind == "CHF":
            self._go(where, list(start), rapid=False, feed=feed)
            return
        bisector = (u[0] + v[0], u[1] + v[1])
        norm = math.hypot(*bisector)
        reach = size / math.sin(theta / 2)
        centre = (p1[0] + bisector[0] / norm * reach, p1[1] + bisector[1] / norm * reach)
        # turning left (counter-clockwise) when the next line bends to the left of the last
        incoming = (-u[0], -u[1])
        clockwise = incoming[0] * v[1] - incoming[1] * v[0] < 0
        self._arc(where, list(start), centre, plane, clockwise=clockwise, feed=feed)

    # ------------------------------------------------------------------ M functions
    def _m_functions(self, item: _Line, text: str) -> None:
        for match in re.finditer(r"\bM(\d+)\b", text):
            code = int(match.group(1))
            if float(code) not in codes.HEIDENHAIN_M:
                self.error(item, f"M{code} is not an M function of the TNC")
                continue
            if code in (3, 4, 13, 14):
                self.spindle_on = True
            elif code in (5, 0):
                self.spindle_on = code != 5 and self.spindle_on
            elif code in (2, 30):
                if self.frames and self.frames[-1].kind == "main":
                    self._finish(self.main)
                    if self.main.end is not None:
                        self._check_end(self.main.end)
                    self.ended = True
                    raise _Stop
            elif code == 99 and self.cycle is not None:
                self._drill(item)
            elif code == 99:
                self.error(item, "M99 calls a cycle, but no cycle is defined")
            elif code == 89:
                self.m89 = True

    # ------------------------------------------------------------------ labels and calls
    def _call_label(self, item: _Line, frame: _Frame, rest: str) -> None:
        parts = rest.split(" REP")
        label = _label(parts[0])
        index = self._label_index(frame.program, label)
        if index is None:
            self.error(item, f"label {label} is not defined")
            return
        call_index = frame.pc - 1
        if len(parts) > 1 and index < call_index:
            key = (id(frame), call_index)
            remaining = self.repeats.get(key)
            if remaining is None:
                match = re.match(r"^\s*(\d+)", parts[1])
                remaining = int(match.group(1)) if match else 1
            if remaining > 0:
                self.repeats[key] = remaining - 1
                self._jump(item)
                frame.pc = index + 1
            else:
                self.repeats.pop(key, None)
            return
        if len(self.frames) > _CALL_NEST:
            self.error(item, f"calls nest deeper than {_CALL_NEST} levels")
            return
        call_line = frame.call_line if frame.kind != "main" else item.line
        self.frames.append(_Frame(frame.program, index + 1, "lbl", call_line, label))

    def _call_program(self, item: _Line, target: str) -> None:
        # the name as written (file names keep their case), quoted or not
        written = re.search(r'CALL\s+PGM\s+"?([^"\s;]+)', item.raw, re.IGNORECASE)
        name = written.group(1) if written else target.strip()
        if name not in self.called:
            text = None
            if self.library is not None and name:
                try:
                    text = self.library(name)
                except Exception:  # a library callback must not break the dry run
                    text = None
            self.called[name] = (
                None if text is None else self._program(TextSource(text), name, external=True)
            )
        program = self.called[name]
        if program is None:
            self.report(item, Severity.WARNING, f"CALL PGM {name}: not in the library")
            return
        if len(self.frames) > _CALL_NEST:
            self.error(item, f"calls nest deeper than {_CALL_NEST} levels")
            return
        # the called program's own first line is its BEGIN PGM: skip it
        first = self._piece(program, 0)
        start = 1 if first is not None and first.texts[0].startswith("BEGIN PGM") else 0
        call_line = self.frames[-1].call_line if self.frames[-1].kind != "main" else item.line
        self.frames.append(_Frame(program, start, "pgm", call_line))

    def _jump(self, item: _Line) -> None:
        count = self.jumps.get(item.line)
        if count is None:
            self.jump_items[item.line] = item
        self.jumps[item.line] = (count or 0) + 1

    def _fn(self, item: _Line, frame: _Frame) -> None:
        match = re.match(r"^FN\s*(\d+)\s*:?\s*(.*)$", item.text)
        if match is None:
            self.error(item, "FN without a function number")
            return
        number, body = int(match.group(1)), match.group(2)
        if number <= 8 or number == 13:
            if "=" not in body:
                self.error(item, f"FN {number} needs Q... = ...")
                return
            # the line names its function itself: FN 6: Q20 = SIN-Q5, FN 13: Q1 = +25 ANG -Q2
            target, formula = body.split("=", 1)
            self.q[target.strip()] = self.formula(formula)
        elif 9 <= number <= 12:
            # split with partition and one search: linear on any line (no backtracking)
            condition, goto, target = body.partition("GOTO LBL")
            compare = re.search(r"\s(EQU|NE|GT|LT)\s", condition)
            if not condition.startswith("IF") or not goto or compare is None:
                self.error(item, f"FN {number} needs IF ... GOTO LBL ...")
                return
            left = self.formula(condition[2 : compare.start()])
            right = self.formula(condition[compare.end() :])
            taken = {
                "EQU": left == right,
                "NE": left != right,
                "GT": left > right,
                "LT": left < right,
            }[compare.group(1)]
            if taken:
                label = _label(target)
                index = self._label_index(frame.program, label)
                if index is None:
                    self.error(item, f"label {label} is not defined")
                    return
                if index < frame.pc:
                    self._jump(item)
                frame.pc = index + 1
        elif number == 14:
            self.report(item, Severity.WARNING, f"the program stops with an error ({body.strip()})")
            raise _Stop
        else:
            self.warn_once(item, f"FN{number}", f"FN {number} is not simulated by the dry run")
            # FN 18: SYSREAD Q5 = ID..., FN 26-28 and others: the target is set (to a value
            # the dry run does not know, 0), so reading it later is no "read before set"
            named = body.partition("=")[0].split() if "=" in body else []
            target = _Q_PARAM.match(named[-1]) if named else None
            if target is not None:
                self.q.setdefault(target.group(0), 0.0)

    # ------------------------------------------------------------------ cycles
    def _cycle_def(self, item: _Line) -> None:
        match = re.match(r"^CYCL DEF\s+(\d+)(?:\.(\d+))?", item.text)
        if match is None:
            self.error(item, "CYCL DEF without a cycle number")
            return
        number = int(match.group(1))
        sub = int(match.group(2) or 0)
        if number == 7:
            if sub >= 1:
                for inc, axis, value in self._axes(item.text.split(None, 3)[-1]):
                    index = "XYZ".find(axis)
                    if index >= 0:
                        self.shift[index] = self.shift[index] + value if inc else value
            return
        if number in _DEF_ACTIVE:
            message = f"cycle {number} is not simulated by the dry run"
            self.warn_once(item, f"cycle{number}", message)
            return
        if sub >= 1 and self.cycle is not None and self.cycle[0] == number:
            return  # an old-style cycle's parameter block (CYCL DEF 1.1 SET UP 2)
        params: dict[str, float] = {}
        words: dict[str, str] = {}
        for text in [item.text, *item.params]:
            for name, sign, token, word in _CYCLE_PARAM.findall(text):
                if word:
                    words[name] = word
                else:
                    params[name] = self.number(sign, token)
        self.cycle_words = words
        depth = params.get("Q201")
        if 200 <= number <= 209 and depth is not None and depth > 0:
            # a control alarm, not a warning: displayDepthErr is on by default (TNC)
            self.error(item, f"cycle {number}: depth Q201 is positive (the TNC stops: wrong sign)")
        if number in _DRILLING:
            needed = ["Q200", "Q201", "Q206", "Q203", "Q204"]
            missing = [q for q in needed if q not in params and q not in words]
            if missing:
                self.error(item, f"cycle {number} without {', '.join(missing)}")
                self.cycle = (number, {}, item.line)  # still defined: no second error at CALL
                return
            if depth == 0:
                self.report(item, Severity.WARNING, f"cycle {number}: depth Q201 is 0 (no hole)")
        else:
            self.warn_once(item, f"cycle{number}", f"cycle {number} is not drawn by the dry run")
        self.cycle = (number, params, item.line)

    def _pattern(self, item: _Line) -> None:
        text = " ".join([item.text, *item.params])
        self.pattern = []
        # up to the last ")": a "(" with no ")" after it would be scanned to the end once a
        # POS, quadratic on a long line; cut there, every search ends at the next ")"
        for body in re.findall(r"POS\d+\s*\(([^)]*)\)", text[: text.rfind(")") + 1]):
            point: list[float | None] = [None, None, None]
            for inc, axis, value in self._axes(body):
                index = "XYZ".find(axis)
                if index >= 0 and not inc:
                    point[index] = value + self.shift[index]
            self.pattern.append((point[0], point[1], point[2]))
        if not self.pattern:
            self.warn_once(item, "pattern", "only PATTERN DEF POS points are simulated")

    def _cycle_call(self, item: _Line, rest: str) -> None:
        if self.cycle is None:
            self.error(item, "CYCL CALL without a cycle defined (CYCL DEF)")
            return
        if rest.startswith("PAT"):
            a, b, _ = self._plane()
            for point in self.pattern:
                target = self.pos[:]
                target[a], target[b] = point[a], point[b]
                self._go(item, target, rapid=True, feed=None)
                c = 3 - a - b
                height = point[c]  # the pattern's own surface, added to Q203 (TNC)
                self._drill(item, surface=None if height is None else height - self.shift[c])
        elif rest.startswith("POS"):
            self._go(item, self._target(rest[3:]), rapid=True, feed=None)
            self._drill(item)
        else:
            self._drill(item)
        self._m_functions(item, rest)

    def _drill(self, item: _Line, surface: float | None = None) -> None:
        assert self.cycle is not None
        number, q, _ = self.cycle
        if number not in _DRILLING or "Q201" not in q:
            return  # a cycle the dry run does not draw, a PREDEF depth, or one reported
        axis = self.axis
        # PREDEF values come from GLOBAL DEF, which the dry run does not read: 0 (Ours)
        top = (surface if surface is not None else 0.0) + q.get("Q203", 0.0) + self.shift[axis]
        clearance = top + q.get("Q200", 0.0)
        second = top + max(q.get("Q204", 0.0), q.get("Q200", 0.0))
        # AUTO / FAUTO / FMAX plunge: the tool's feed from TOOL CALL (or the feed in force)
        feed = q.get("Q206", self.tool_feed or self.feed)
        if not self.spindle_on:
            self.warn_once(item, "spindle", "a cutting move with the spindle stopped")
        for height, rapid in (
            (clearance, True),
            (top + q["Q201"], False),
        ):
            target = self.pos[:]
            target[axis] = height
            self._go(item, target, rapid=rapid, feed=None if rapid else feed)
        self.path.dwell(q.get("Q211", 0.0) + q.get("Q210", 0.0))
        back_feed = q.get("Q208", 0.0) or feed if number == 201 else None
        target = self.pos[:]
        target[axis] = clearance
        self._go(item, target, rapid=back_feed is None, feed=back_feed)
        target = self.pos[:]
        target[axis] = second
        self._go(item, target, rapid=True, feed=None)

    # ------------------------------------------------------------------ result
    def result(self) -> CheckResult:
        problems = list(self.problems.values())
        if self.machine is not None:
            problems += self.path.travel_problems(self.machine.name)
        if self.more_problems:
            problems = problems[:MAX_PROBLEMS]
        result = self.path.result(
            Control.HEIDENHAIN,
            self.name,
            problems,
            stock=self.stock,
            units=self.units,
            blocks=self.blocks_run,
            end=EndState(
                position={a: v for a, v in zip("XYZ", self.pos, strict=True) if v is not None},
                tool=self.tool,
                variables={int(k[1:]): v for k, v in self.q.items() if k[1:].isdigit()},
                ended=self.ended,
            ),
        )
        if not self.more_problems:
            return result
        return replace(result, more_problems=self.more_problems, more_errors=self.more_errors)


_KNOWN_HEADS = frozenset(
    {
        "L", "LN", "LP", "C", "CR", "CT", "CP", "CC", "RND", "CHF", "APPR", "DEP", "BEGIN",
        "END", "BLK", "TOOL", "LBL", "CALL", "FN", "CYCL", "PATTERN", "STOP", "PLANE",
        "FUNCTION", "TCH", "SEL", "DECLARE",
    }
)  # fmt: skip
_M_WORD = re.compile(r"\bM(\d+)\b")
_M_HEADS = frozenset({"L", "LN", "LP", "C", "CR", "CT", "CP", "APPR", "DEP", "RND", "CHF", "STOP"})


def _plain_axes(text: str) -> _Axes | None:
    """The numbers of X, Y, Z and F (as written; None: not there) of a straight move with
    absolute literal coordinates only, at most R0 and F (_PLAIN_L), or None."""
    xyz = _PLAIN_XYZ.fullmatch(text)
    if xyz is not None:
        x, y, z, feed = xyz.groups()
        return x, y, z, feed
    plain = _PLAIN_L.fullmatch(text)
    if plain is None:
        return None
    words = {word[0]: word[1:] for word in plain.group(1).split()}  # the last of an axis counts
    return words.get("X"), words.get("Y"), words.get("Z"), plain.group(2)


def _static_problem(text: str) -> str | None:
    """An unknown block keyword or M function, found without running the block."""
    head = text.split(" ", 1)[0] if text else ""
    if not (
        head in _KNOWN_HEADS
        or text.startswith("*")
        or re.match(r"^(Q|QL|QR|QS)\d+\s*=", text)
        or re.match(r"^M\d+\b", text)
    ):
        return f"unknown block {head!r}"
    if "M" not in text or not (head in _M_HEADS or text.startswith(("CYCL CALL", "M"))):
        return None  # names (BEGIN PGM M100, CALL PGM M5.H, LBL) are not M functions
    for match in _M_WORD.finditer(_STRING.sub("", text)):
        if float(match.group(1)) not in codes.HEIDENHAIN_M:
            return f"M{int(match.group(1))} is not an M function of the TNC"
    return None


# blocks whose raw line is kept: the case of their text matters (tool and program names)
_CASE_KEPT = ("TOOL CALL", "CALL PGM")


def _decimal_comma(text: str) -> tuple[str, str | None]:
    """``text`` with ``10,5`` read as ``10.5`` outside strings, and the error to report.

    The TNC writes and reads numbers with a decimal point; a comma is an error, never a
    silent ``10`` (docs/check.md#klartext). The dry run then draws the number as meant.
    """
    parts = re.split(r'("[^"]*")', text)
    found = None
    for index in range(0, len(parts), 2):
        match = _DECIMAL_COMMA.search(parts[index])
        if match is None:
            continue
        if found is None:
            number = _COMMA_NUMBER.search(parts[index])
            found = number.group(0) if number else match.group(0)
        parts[index] = _DECIMAL_COMMA.sub(r"\1.\2", parts[index])
    if found is None:
        return text, None
    fixed = found.replace(",", ".")
    message = f"a decimal comma ({found}): the TNC reads a decimal point only (write {fixed})"
    return "".join(parts), message


def _label(text: str) -> str:
    """A label as written: a number (``1``) or a name (``"CONTOUR"``, kept without quotes)."""
    text = text.strip()
    match = _STRING.match(text)
    if match:
        return match.group(1)
    token = text.split()[0] if text.split() else ""
    return token.lstrip("+") if token else ""


def run_klartext(
    source: Source,
    *,
    name: str,
    machine: MachineLimits | None,
    library: Library | None,
    budget: Budget,
) -> CheckResult:
    """Dry-run a Klartext program (see the module docstring)."""
    run = _Run(source, name, machine, library, budget)
    run.run()
    return run.result()
