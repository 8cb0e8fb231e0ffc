"""The G-code dry run: Haas / Fanuc macro B (and Heidenhain ISO programs).

Every line goes through the parser of :mod:`opendnc.gcode.program` first (syntax, words
without a value, unknown G/M codes, GOTO targets, WHILE/END pairs: also on lines the run
never reaches); then the program runs from its first block with the macro engine of the
same module: variables and the read-only table of :mod:`opendnc.haas.macros`, IF/GOTO/WHILE,
sub-programs (M97, M98, M99, G65), and motion (modal groups, G0-G3, planes, units,
absolute/incremental, work offsets, G28/G53, tools, canned cycles as holes). A fault the
control would stop on (division by zero, a write to a read-only variable, a GOTO to no
block) ends the run there, as an alarm would. docs/check.md#g-code has the rules.
"""

from __future__ import annotations

import math
import re
import time
from array import array
from collections.abc import Iterator
from dataclasses import dataclass, field, replace

from opendnc.errors import InputError
from opendnc.gcode.program import (
    Assign,
    Block,
    Dprnt,
    EndLoop,
    Expr,
    Goto,
    IfGoto,
    IfThen,
    Num,
    PlainWords,
    PortControl,
    While,
    Words,
    evaluate,
    parse_axes,
    parse_block,
    parse_plain,
    unset_variables,
    variable_number,
)
from opendnc.haas import macros
from opendnc.nccheck import codes
from opendnc.nccheck.api import Budget, Library
from opendnc.nccheck.dialects import Dialect, dialect_named, guess_dialect, lathe_word
from opendnc.nccheck.limits import MachineLimits, offset_key
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
    Units,
)
from opendnc.nccheck.source import Source, TextSource

__all__ = ["run_gcode"]

_O_LINE = re.compile(r"^\s*[O:](\d{1,5})\b")
_ISO_LINE = re.compile(r"^\s*%\s*(\w[\w.-]*)")
# possessive runs (*+): adjacent blank and digit runs would otherwise be split every way on
# a long line of blanks that fails to match, quadratic
_ISO_END = re.compile(r"^\s*+N?\d*+\s*+%\s*+\w[\w.-]*+\s+G7[01]", re.IGNORECASE)
_N_ONLY = re.compile(r"^\s*+/?\s*+N\s*+(\d+)", re.IGNORECASE)
_COMMENT_TEXT = re.compile(r"\(([^)]*)\)")

# Fanuc macro-B argument specification I: address -> local variable
_ARGUMENTS = {
    "A": 1, "B": 2, "C": 3, "I": 4, "J": 5, "K": 6, "D": 7, "E": 8, "F": 9, "H": 11,
    "M": 13, "Q": 17, "R": 18, "S": 19, "T": 20, "U": 21, "V": 22, "W": 23, "X": 24,
    "Y": 25, "Z": 26,
}  # fmt: skip
_MAX_NESTING = 20
_AXES = "XYZ"
_AXIS_INDEX = (("X", 0), ("Y", 1), ("Z", 2))
_FAST_LETTERS = frozenset("XYZF")
# G31 skip (probe) moves, G36 work offset and G37 tool length measurement: feed moves
# made with the spindle stopped on purpose (Haas mill, Fanuc M)
_PROBE_MOVES = frozenset((31.0, 36.0, 37.0))
# non-modal codes that decide a block's motion themselves (Haas / Fanuc; not Heidenhain ISO)
_SPECIAL = frozenset((10.0, 28.0, 53.0, 65.0, 92.0, 52.0)) | _PROBE_MOVES
_LATHE_MAX_RPM = 4000.0  # a spindle clamp when the program gives none (G50 S): Ours
_COMMENT_ONLY = re.compile(r"^(?:\([^)]*\)\s*)+$")


_Parsed = Block | PlainWords | dict[str, float]
"""A block as the run keeps it: a :class:`Block`, the words of a plain block, or the values
of a block of X/Y/Z/F words only by letter (the bulk of a surface program)."""


def _negative(letter: str, value: float) -> str:
    # A feed or a spindle speed has no sign: the control refuses a minus after F or S (Fanuc
    # P/S alarm 006, "illegal use of negative sign"; docs/check.md#g-code)
    what = "feed rate" if letter == "F" else "spindle speed"
    return f"{letter}{value:g}: a {what} cannot be negative"


class _Stop(Exception):
    """The run ends here (program end, alarm, budget)."""


_CHUNK = 256  # blocks per piece a program is re-read in (a power of two: index >> 8)
_SHIFT = 8
_CACHED = 64  # pieces kept parsed (about 16,000 blocks) for loops and sub-programs


@dataclass
class _Program:
    """A program of the file, read as the run needs it: its blocks are parsed as the scan
    reaches them and forgotten again; what stays is where each piece of 256 blocks starts
    in the file (to read it again on a jump back), its N numbers and its WHILE/END pairs."""

    name: str
    number: int | None
    source: Source | None = None
    count: int = 0  # blocks scanned so far
    complete: bool = False  # the scan has passed its last block
    first_line: int = 0
    last_line: int = 0
    offsets: array[int] = field(default_factory=lambda: array("q"))  # piece -> file offset
    starts: array[int] = field(default_factory=lambda: array("q"))  # piece -> file line
    tail: list[tuple[int, _Parsed]] = field(default_factory=list)  # last piece
    numbers: dict[int, int] = field(default_factory=dict)  # N -> block index
    loop_end: dict[int, int] = field(default_factory=dict)  # WHILE index -> END index
    loop_start: dict[int, int] = field(default_factory=dict)  # END index -> WHILE index
    stacks: dict[int, list[tuple[int, int]]] = field(default_factory=dict)  # open WHILEs
    gotos: list[tuple[int, int]] = field(default_factory=list)  # (line, N) of literal GOTOs
    external: bool = False


@dataclass
class _Frame:
    program: _Program
    pc: int
    locals: dict[int, float]
    kind: str  # main, m97, m98, g65, cycle (a lathe contour P..Q)
    call_line: int  # file line of the outermost call (the main program's line)
    repeat: int = 1
    start: int = 0
    stop: int = -1  # a lathe contour's last block (its frame ends after it); -1: none


@dataclass
class _Cycle:
    code: float
    z: float | None = None  # bottom, absolute work Z
    r: float | None = None  # R plane, absolute work Z
    initial: float | None = None
    dwell: float = 0.0
    peck_checked: bool = False


class _Run:
    def __init__(
        self,
        source: Source,
        control: Control,
        name: str,
        machine: MachineLimits | None,
        library: Library | None,
        budget: Budget,
    ) -> None:
        self.control = control
        self.iso = control is Control.ISO
        self.name = name
        self.machine = machine
        self.library = library
        self.budget = budget
        self.problems: dict[tuple[int, str], Problem] = {}
        named = machine.dialect if machine is not None else None
        self.dialect: Dialect = (
            dialect_named(named) if named else guess_dialect(source.head(1 << 20))
        )
        self.lathe = self.dialect.lathe and not self.iso
        # words whose number without a decimal point counts in the least input increment
        self.bare = "" if self.iso else self.dialect.bare_letters
        self.g_codes = codes.ISO_G if self.iso else self.dialect.g_codes
        self.m_codes = codes.HEIDENHAIN_M if self.iso else self.dialect.m_codes
        travel = dict(machine.travel) if machine and machine.travel else None
        rapid = (machine.rapid_rate if machine else None) or RAPID_MM_PER_MIN
        self.path = Toolpath(max_moves=budget.moves, rapid_rate=rapid, travel=travel)
        self.globals: dict[int, float] = {}
        self.programs: dict[int, _Program] = {}
        self.missing: set[int] = set()  # called programs the library does not have
        self.frames: list[_Frame] = []
        self.warned: set[str] = set()
        self.header_units: Units | None = None
        self.source = source
        self.cache: dict[tuple[int, int], list[tuple[int, _Parsed]]] = {}
        self.scanned = 0  # blocks the scan has read (each once: a loop's passes are not)
        self._scan = self._scanner()
        self.scan_done = False
        # the scan runs ahead to the main program's first block (and its ISO header)
        self.main = self._first_program()
        # modal state
        self.units: Units | None = self.header_units
        self.motion = 0.0
        self.plane = Plane.ZX if self.lathe else Plane.XY
        self.absolute = True
        self.iso_centre: dict[str, float] = {}  # Heidenhain ISO: I/J/K in force (like CC)
        self.feed_mode = 95 if self.lathe else 94  # lathes power on in feed per revolution
        self.feed: float | None = None
        self.speed = 0.0
        self.block_words: dict[str, float] = {}
        self.spindle_on = False
        self.spindle_stop: tuple[str, int] | None = None  # what stopped it, and where
        self.stopped_cut_reported = False
        self.rigid_tap = False  # Fanuc M29: the next G84 turns the spindle itself
        self.comp = 40.0  # cutter compensation G40 / G41 / G42
        self.d_word: float | None = None  # D in force (cutter radius offset number)
        self.h_word: float | None = None  # H in force (tool length offset number)
        self.css: float | None = None  # lathe G96 surface speed (None: G97 rpm)
        self.max_rpm: float | None = None  # lathe G50 S clamp
        self.timer_base = 0.0  # #3001 = n sets the millisecond timer to n
        self.work_offset = 54.0
        self.cycle: _Cycle | None = None
        self.cycle_return_r = False  # G99
        self.next_tool: int | None = None
        self.tool: int | None = None
        self.counters = [0, 0]
        self.w: list[float | None] = [None, None, None]  # work position
        self.m: list[float | None] = [None, None, None]  # machine position
        if self.lathe:  # most lathes have no Y axis: it stays at 0 so moves are drawn
            self.w[1] = self.m[1] = 0.0
        self.prev_end: list[float | None] = [None, None, None]
        self.off: list[float | None] = [0.0, 0.0, 0.0]
        self.blocks_run = 0
        self.jumps: dict[int, int] = {}
        self.jump_detail: dict[int, str] = {}
        self.no_feed_reported = False
        self.locals: dict[int, float] = {}
        self.main_locals = self.locals
        self.ended = False
        self.configured: dict[int, float] = {}  # offsets from the machine's configuration
        self.converted = False
        if machine is not None:
            for key, axes in machine.work_offsets.items():
                base = _offset_base(key)
                if base is not None:
                    for index, letter in enumerate("XYZABC"):
                        if letter in axes:
                            self.globals[base + index] = axes[letter]
                            self.configured[base + index] = axes[letter]
        if self.units is not None:
            self._convert_machine_units(self.units)
        self._offsets()
        if named and not self.dialect.lathe and not self.iso:
            # a lathe program checked as a mill program: X is a radius there, U/W and T0101
            # mean other things, and moves may never be measured (no Y): say so
            found = lathe_word(source.head(1 << 20))
            if found is not None:
                self.report(
                    found[0],
                    Severity.WARNING,
                    f"'{found[1]}' is a lathe block, but the program is checked as a "
                    f"{self.dialect.title} program: name the lathe control if it is one",
                )

    # ------------------------------------------------------------------ reporting
    def report(self, line: int, severity: Severity, message: str) -> None:
        frame = self.frames[-1] if self.frames else None
        if frame is not None and frame.program.external:
            message = f"in {frame.program.name} line {line}: {message}"
            line = frame.call_line
        self.problems.setdefault((line, message), Problem(line, severity, message))

    def error(self, line: int, message: str) -> None:
        self.report(line, Severity.ERROR, message)

    def warn_once(self, line: int, key: str, message: str) -> None:
        if key not in self.warned:
            self.warned.add(key)
            self.report(line, Severity.WARNING, message)

    # ------------------------------------------------------------------ program text
    def _first_program(self) -> _Program:
        self.programs_seen: list[_Program] = []
        while not self.programs_seen or (
            not self.programs_seen[0].count and not self.programs_seen[0].complete
        ):
            if not self._advance():
                break
        if not self.programs_seen:  # an empty file
            self.programs_seen.append(
                _Program(self.name or "program", None, self.source, complete=True)
            )
        return self.programs_seen[0]

    def _advance(self) -> bool:
        """Scan one more block of the file; False at its end."""
        if self.scan_done:
            return False
        if next(self._scan, None) is None:
            self.scan_done = True
            return False
        return True

    def _scanner(self) -> Iterator[bool]:
        """Read the file in order: split it into programs (the first is the main one, the
        others callable by O number), check every block once (also those the run never
        reaches) and remember where each piece of blocks starts. Yields after each piece
        of blocks (and after an ISO end block)."""
        self.iso_ended = False
        held: list[tuple[int, int, str]] = []  # comment lines before the first O line
        title: tuple[str, int | None] = (self.name or "program", None)
        current: _Program | None = None
        for index, offset, line in self.source.lines():
            stripped = line.strip().strip("\x1a")
            if not stripped or stripped == "%":
                continue
            if self.iso:
                if current is None and not held and (match := _ISO_LINE.match(stripped)):
                    title = (match.group(1), None)
                    if re.search(r"\bG70\b", stripped):
                        self.header_units = Units.INCH
                    elif re.search(r"\bG71\b", stripped):
                        self.header_units = Units.MM
                    continue
                if _ISO_END.match(stripped):
                    self.iso_ended = True
                    if current is None:
                        current = self._new_program(title)
                    self._add(current, index, offset, "M30")  # END of an ISO program
                    yield True
                    continue
            elif stripped[0] in "O:" or stripped[0].isspace():  # all _O_LINE can match
                match = _O_LINE.match(stripped)
                if match is not None:
                    if current is None and held and _only_comments(held):
                        held = []  # a title comment before the O line: part of this one
                    if held:
                        current = self._new_program(title)
                        for item in held:
                            self._add(current, *item)
                        held = []
                    if current is not None or title[1] is not None:
                        if current is None:
                            current = self._new_program(title)
                        self._close(current)
                    number = int(match.group(1))
                    title = (f"O{number:05d}", number)
                    current = None
                    continue
            text = stripped.rstrip("*").rstrip() if self.iso else stripped
            first = current is None and not self.iso and not self.programs_seen
            if first and len(held) < 64 and _COMMENT_ONLY.match(text):
                held.append((index, offset, text))  # may be a title before an O line
                continue
            if current is None:
                current = self._new_program(title)
                for item in held:
                    self._add(current, *item)
                held = []
            self._add(current, index, offset, text)
            if not current.count & (_CHUNK - 1):
                yield True  # a piece at a time: a resumption a block costs as much as its check
        if current is None:
            current = self._new_program(title)
            for item in held:
                self._add(current, *item)
        self._close(current)
        if self.iso and current.count and not self.iso_ended:
            # the TNC needs the end block N99999999 %NAME G71 (docs/check.md#heidenhain-iso)
            self._static(
                current,
                current.last_line,
                f"the ISO program has no end block (N99999999 %{title[0]})",
            )

    def _new_program(self, title: tuple[str, int | None]) -> _Program:
        program = _Program(title[0], title[1], self.source)
        self.programs_seen.append(program)
        if program.number is not None:
            self.programs.setdefault(program.number, program)
        return program

    def _add(self, program: _Program, line: int, offset: int, text: str) -> None:
        """Parse and check one block, and note it in ``program``."""
        index = program.count
        if not index & (_CHUNK - 1):
            if program.tail:  # the piece before is complete: parsed, it stays a while
                self._keep(program, (index >> _SHIFT) - 1, program.tail)
            program.tail = []
            program.offsets.append(offset)
            program.starts.append(line)
        if not index:
            program.first_line = line
        block = self._parse(program, line, text, index, check=True)
        program.tail.append((line, block))
        program.count = index + 1
        program.last_line = line
        self.scanned += 1

    def _keep(self, program: _Program, piece: int, blocks: list[tuple[int, _Parsed]]) -> None:
        cache = self.cache
        if len(cache) >= _CACHED:
            del cache[next(iter(cache))]  # the oldest piece goes
        cache[(id(program), piece)] = blocks

    def _close(self, program: _Program) -> None:
        """The scan has passed the last block of ``program``: the checks that need all of it."""
        program.complete = True
        for loop, stack in program.stacks.items():
            for _, line in stack:
                self._static(program, line, f"WHILE ... DO{loop} without END{loop}")
        program.stacks = {}
        for line, target in program.gotos:
            if target not in program.numbers:
                self._static(program, line, f"GOTO {target}: no block N{target} in {program.name}")
        program.gotos = []

    def _parse(
        self, program: _Program, line: int, text: str, index: int, *, check: bool
    ) -> _Parsed:
        """One block; with ``check`` (its first reading) its static checks and its N number,
        WHILE/END pair and GOTO target are noted too."""
        axes = parse_axes(text)
        if axes is not None:  # X/Y/Z/F only: no code to look up
            if check and axes[0] is not None:
                program.numbers.setdefault(axes[0], index)
            return axes[1]
        plain = parse_plain(text)
        if plain is not None:
            number, words = plain
            if check:
                if number is not None:
                    program.numbers.setdefault(number, index)
                if "G" not in text and "M" not in text:
                    return words  # no code to look up (most blocks: X/Y/Z moves)
                g_codes, m_codes = self.g_codes, self.m_codes
                for letter, value in words:
                    if (letter == "G" and value not in g_codes) or (
                        letter == "M" and value not in m_codes
                    ):
                        message = self._code_problem(letter, value)
                        if message:
                            self._static(program, line, message)
            return words
        try:
            block = parse_block(text)
        except RecursionError:
            if check:
                self._static(program, line, "an expression nested too deeply")
            return Block(text)
        except InputError as exc:
            if check:
                if self.iso:
                    # ISO cycles and Q-parameter lines are beyond the macro-B parser
                    self.warn_once(line, "iso-line", "ISO cycle and Q-parameter lines are not "
                                   "simulated by the dry run")  # fmt: skip
                else:
                    self._static(program, line, str(exc).split(" in block ")[0])
            return Block(text)
        if not check:
            return block
        if block.number is not None:
            program.numbers.setdefault(block.number, index)
        statement = block.statement
        if isinstance(statement, Words):
            self._check_codes(program, line, statement)
        elif isinstance(statement, While):
            program.stacks.setdefault(statement.loop, []).append((index, line))
        elif isinstance(statement, EndLoop):
            stack = program.stacks.get(statement.loop)
            if stack:
                start = stack.pop()[0]
                program.loop_end[start] = index
                program.loop_start[index] = start
            else:
                self._static(
                    program, line, f"END{statement.loop} without WHILE ... DO{statement.loop}"
                )
        if isinstance(statement, Goto | IfGoto) and isinstance(statement.target, Num):
            program.gotos.append((line, round(statement.target.value)))
        return block

    def _block(self, program: _Program, index: int) -> tuple[int, _Parsed] | None:
        """Block ``index`` of ``program`` with its file line; None past its last block."""
        blocks = self._piece(program, index)
        return None if blocks is None else blocks[index & (_CHUNK - 1)]

    def _piece(self, program: _Program, index: int) -> list[tuple[int, _Parsed]] | None:
        """The piece of ``program`` that holds block ``index`` (read on to it, or again from
        the file); None past its last block. The last piece may grow as the scan goes on."""
        while index >= program.count:
            # the scan's last step may add the blocks asked for as it ends
            if (program.complete or not self._advance()) and index >= program.count:
                return None
        piece = index >> _SHIFT
        if piece == len(program.offsets) - 1:
            return program.tail
        blocks = self.cache.get((id(program), piece))
        if blocks is None:
            blocks = self._reread(program, piece)
            self._keep(program, piece, blocks)
        return blocks

    def _reread(self, program: _Program, piece: int) -> list[tuple[int, _Parsed]]:
        """Read a piece of ``program`` from the file again (a jump back to it)."""
        assert program.source is not None
        out: list[tuple[int, _Parsed]] = []
        index = piece << _SHIFT
        for line, _, text in program.source.lines(program.offsets[piece], program.starts[piece]):
            stripped = text.strip().strip("\x1a")
            if not stripped or stripped == "%":
                continue
            if self.iso:  # as the scan read it
                end = _ISO_END.match(stripped)
                stripped = "M30" if end else stripped.rstrip("*").rstrip()
            out.append((line, self._parse(program, line, stripped, index + len(out), check=False)))
            if len(out) == _CHUNK:
                break
        return out

    def _number(self, program: _Program, number: int) -> int | None:
        """The index of block N``number`` of ``program`` (the scan reads on to find it)."""
        found = program.numbers.get(number)
        while found is None and not program.complete:
            more = self._advance()
            found = program.numbers.get(number)
            if not more:
                break
        return found

    def _loop_end(self, program: _Program, index: int) -> int | None:
        """The END paired with the WHILE at ``index`` (the scan reads on to find it)."""
        found = program.loop_end.get(index)
        while found is None and not program.complete:
            more = self._advance()
            found = program.loop_end.get(index)
            if not more:
                break
        return found

    def _line_of(self, program: _Program, index: int) -> int:
        entry = self._block(program, index)
        return entry[0] if entry else program.last_line or 1

    def _finish_scan(self) -> None:
        """Scan the rest of the file: its blocks are checked even where the run never went."""
        while self._advance():
            pass

    def _static(self, program: _Program, line: int, message: str) -> None:
        if program.external:
            message = f"in {program.name} line {line}: {message}"
            line = self.frames[-1].call_line if self.frames else line
        self.problems.setdefault((line, message), Problem(line, Severity.ERROR, message))

    def _check_codes(self, program: _Program, line: int, words: Words) -> None:
        for letter, expr in words.words:
            if letter in "GM" and isinstance(expr, Num):
                message = self._code_problem(letter, expr.value)
                if message:
                    self._static(program, line, message)

    def _code_problem(self, letter: str, value: float) -> str | None:
        table = self.g_codes if letter == "G" else self.m_codes
        if value in table:
            return None
        m_from = self.dialect.m_from
        if letter == "M" and not self.iso and m_from is not None and value >= m_from:
            return None
        control = "Heidenhain ISO" if self.iso else self.dialect.title
        return f"{letter}{value:g} is not a {letter} code of the {control} control"

    # ------------------------------------------------------------------ variables
    def get(self, number: int) -> float | None:
        if 1 <= number <= 33:
            return self.locals.get(number)
        if number < 1000:
            return None if number == 0 else self.globals.get(number)
        if 5000 < number < 5100:
            return self._position_variable(number)
        if 4000 < number < 4200:
            return self._modal_variable(number)
        if number == 3001:
            return self.path.seconds * 1000.0 - self.timer_base
        if number == 3026:
            return float(self.tool) if self.tool is not None else 0.0
        if number == 3027:
            return self.speed
        if number in (3901, 3902):
            return float(self.counters[number - 3901])
        return self.globals.get(number)

    def _position_variable(self, number: int) -> float | None:
        for base, values in ((5001, self.prev_end), (5021, self.m), (5041, self.w)):
            if base <= number < base + 3:
                return values[number - base]
        return self.globals.get(number)

    def _modal_variable(self, number: int) -> float | None:
        motion = self.cycle.code if self.cycle else self.motion
        table: dict[int, float | None] = {
            4001: motion,
            4002: {Plane.XY: 17.0, Plane.ZX: 18.0, Plane.YZ: 19.0}[self.plane],
            4003: 90.0 if self.absolute else 91.0,
            4005: float(self.feed_mode),
            4006: 20.0 if self.units is Units.INCH else 21.0,
            4010: 99.0 if self.cycle_return_r else 98.0,
            4014: self.work_offset,
            4109: self.feed,
            4119: self.speed,
            4120: float(self.tool) if self.tool is not None else None,
        }
        return table.get(number)

    def set(self, number: int, value: float | None, line: int, source: str) -> None:
        if 1 <= number <= 33:
            if value is None:
                self.locals.pop(number, None)
            else:
                self.locals[number] = value
            return
        if number == macros.ALARM_VARIABLE:
            # Haas: alarm 1000 + n (InputError for a bad number); Fanuc B: alarm 3000 + n
            code = macros.alarm_for(value) if self.dialect.haas else 3000 + int(value or 0)
            # up to the last ")": a search from each "(" with no ")" after it is quadratic
            comment = _COMMENT_TEXT.search(source, 0, source.rfind(")") + 1)
            text = comment.group(1).strip() if comment else "PROGRAMMABLE ALARM"
            # what the control alarms on is an error; the run goes on to find the rest
            self.error(line, f"the program raises alarm {code} ({text})")
            return
        if number in self.dialect.writable:
            if number == 3001:  # the millisecond timer: a program resets it to time a part
                self.timer_base = self.path.seconds * 1000.0 - (value or 0.0)
            else:
                self.globals[number] = value or 0.0
            return
        try:
            stored = macros.check_write(number, value)
        except InputError:
            if self.dialect.haas or macros.lookup(number) is not None:
                raise
            stored = value  # a Fanuc variable the Haas table does not hold
        if number in (3901, 3902):
            self.counters[number - 3901] = int(stored or 0)
        elif stored is None:
            self.globals.pop(number, None)
        else:
            self.globals[number] = stored
        if 5200 <= number <= 5400 or 7000 <= number <= 7400 or 14000 <= number <= 16000:
            self._offsets()

    def value(self, expr: Expr) -> float:
        if type(expr) is Num:
            return expr.value
        result = evaluate(expr, self.get)
        return 0.0 if result is None else result

    def _offsets(self) -> None:
        """The work offset in force per axis (None where the program or config never set it)."""
        base = _work_base(self.work_offset)
        for axis in range(3):
            local = self.globals.get(5201 + axis, 0.0)
            offset = self.globals.get(base + axis) if base is not None else None
            self.off[axis] = None if offset is None else offset + local
        known = [self.m[i] for i in range(3)]
        for axis in range(3):
            offset = self.off[axis]
            machine = known[axis]
            if machine is not None and offset is not None:
                self.w[axis] = machine - offset

    # ------------------------------------------------------------------ the run
    def run(self) -> None:
        # CPU time of this thread: a busy machine must not turn a long program into a "loop"
        seconds = self.budget.seconds
        deadline = math.inf if seconds is None else time.thread_time() + seconds
        # the block budget is for loops: each block of the file runs once outside it
        limit = self.budget.blocks
        frames = self.frames
        frames.append(_Frame(self.main, 0, self.locals, "main", 0))
        axes, plain = self._axes, self._plain
        try:
            while True:
                frame = frames[-1]
                index = frame.pc
                stop = frame.stop
                blocks = self._piece(frame.program, index) if index <= stop or stop < 0 else None
                if blocks is None:
                    self._fall_off(frame)
                    continue
                at = index & (_CHUNK - 1)
                end = len(blocks) if stop < 0 else min(len(blocks), at + stop - index + 1)
                # the blocks of this piece in order, until a jump, a call or a return
                while at < end:
                    line, block = blocks[at]
                    frame.pc = next_pc = index + 1
                    self.blocks_run += 1
                    if self.blocks_run & 1023 == 0 and (
                        self.blocks_run - self.scanned >= limit or time.thread_time() > deadline
                    ):
                        self._endless(line)
                    try:
                        if type(block) is dict:
                            axes(block, frame, line)
                        elif type(block) is tuple:
                            plain(block, frame, line)
                        else:
                            assert isinstance(block, Block)
                            if not block.deleted:
                                self._execute(block, frame, index, line)
                    except InputError as exc:
                        # the control would alarm here; the dry run reports it and goes on
                        # with the next block, so one fault does not hide the ones after it
                        self.error(line, str(exc).split(" in block ")[0])
                    except RecursionError:
                        self.error(line, "an expression nested too deeply")
                    if frame.pc != next_pc or frames[-1] is not frame:
                        break  # a jump, a call or a return: the next block is elsewhere
                    at += 1
                    index = next_pc
        except _Stop:
            pass

    def _fall_off(self, frame: _Frame) -> None:
        program = frame.program
        last = (program.last_line or 1) if frame.stop < 0 else self._line_of(program, frame.stop)
        if frame.kind == "main":
            self.error(last, "no program end (M30, M02 or M99)")
            raise _Stop
        if frame.kind == "cycle":  # the last block of a lathe contour: back to the cycle
            self.frames.pop()
            return
        # the control alarms when a sub-program runs off its end (Fanuc B, Haas mill)
        self.report(last, Severity.ERROR, f"{program.name} ends without M99")
        self._return(frame, last)

    def _endless(self, line: int) -> None:
        self.frames[1:] = []  # report at the main program's line
        if not self.jumps:
            # no jump back: a long program (or deep calls), not a loop. The rest is not
            # checked, so this is an error: a stopped check must never pass as a clean one
            spent = (
                f"{self.budget.blocks:,} blocks run again"
                if self.blocks_run - self.scanned >= self.budget.blocks
                else f"{self.budget.seconds:g} s of CPU"
            )
            self.error(
                line,
                f"the dry run stopped here after {self.blocks_run:,} blocks (its budget of "
                f"{spent} ran out); the rest of the program is not checked",
            )
            raise _Stop
        where, count = max(self.jumps.items(), key=lambda item: item[1])
        self.error(
            where,
            f"endless loop: the jump back at line {where}{self.jump_detail.get(where, '')} "
            f"ran {count:,} times; the dry "
            f"run stopped after {self.blocks_run:,} blocks",
        )
        raise _Stop

    def _jump(self, line: int) -> None:
        frame = self.frames[-1] if self.frames else None
        if frame is not None and frame.program.external:
            # a loop inside a library program: named by its call in this file
            self.jump_detail[frame.call_line] = f" (in {frame.program.name} line {line})"
            line = frame.call_line
        self.jumps[line] = self.jumps.get(line, 0) + 1

    def _execute(self, block: Block, frame: _Frame, index: int, line: int) -> None:
        statement = block.statement
        if type(statement) is Words:
            self._words(statement, frame, line)
        elif isinstance(statement, Assign):
            number = self._target_number(statement.target)
            self.set(number, evaluate(statement.value, self.get), line, block.source)
        elif isinstance(statement, IfThen):
            if self.value(statement.condition):
                then = statement.then
                number = self._target_number(then.target)
                self.set(number, evaluate(then.value, self.get), line, block.source)
        elif isinstance(statement, IfGoto):
            if self.value(statement.condition):
                self._goto(frame, self.value(statement.target), index, line)
        elif isinstance(statement, Goto):
            self._goto(frame, self.value(statement.target), index, line)
        elif isinstance(statement, While):
            if not self.value(statement.condition):
                end = self._loop_end(frame.program, index)
                if end is None:
                    raise InputError(f"WHILE ... DO{statement.loop} without END{statement.loop}")
                frame.pc = end + 1
        elif isinstance(statement, EndLoop):
            start = frame.program.loop_start.get(index)
            if start is None:
                raise InputError(f"END{statement.loop} without WHILE ... DO{statement.loop}")
            self._jump(line)
            frame.pc = start
        elif isinstance(statement, Dprnt | PortControl):
            pass  # output only: nothing moves

    def _target_number(self, target: Expr) -> int:
        """The variable an assignment writes; ``#[#8] = 1`` with #8 unset names #8."""
        number = variable_number(target, self.get)
        if number == 0:
            unset = unset_variables(target, self.get)
            if unset:
                names = ", ".join(f"#{n}" for n in unset)
                verb = "is" if len(unset) == 1 else "are"
                raise InputError(f"the assignment writes #0 because {names} {verb} unset (null)")
        return number

    def _goto(self, frame: _Frame, target: float, index: int, line: int) -> None:
        number = round(target)
        found = self._number(frame.program, number)
        if found is None:
            raise InputError(f"GOTO {number}: no block N{number} in {frame.program.name}")
        if found <= index:
            self._jump(line)
        frame.pc = found

    # ------------------------------------------------------------------ words
    def _plain(self, words: PlainWords, frame: _Frame, line: int) -> None:
        motion = self.motion
        if (motion == 0.0 or motion == 1.0) and self.cycle is None and not self.lathe:
            # X/Y/Z (and F) in G00/G01 (a G00/G01 of their own may come first): _fast_move
            fast: dict[str, float] = {}
            code = None
            bare = False
            for letter, value in words:
                if letter in _FAST_LETTERS:
                    fast[letter] = value
                    if type(value) is int:  # written without a decimal point
                        bare = True
                elif letter == "G" and (value == 0.0 or value == 1.0) and code is None:
                    code = value
                else:
                    break
            else:
                if code is not None:
                    self.motion = code
                if bare and self.bare:
                    self._bare(fast, line)
                self._fast_move(fast, line)
                return
        g: list[float] = []
        m: list[float] = []
        v: dict[str, float] = {}
        for letter, value in words:
            if letter == "G":
                g.append(value)
            elif letter == "M":
                m.append(value)
            else:
                v[letter] = value
        self._apply(g, m, v, frame, line)

    def _axes(self, axes: dict[str, float], frame: _Frame, line: int) -> None:
        """A block of X/Y/Z/F words only, each with a decimal point (parse_axes)."""
        motion = self.motion
        if (motion == 0.0 or motion == 1.0) and self.cycle is None and not self.lathe:
            self._fast_move(axes, line)
        else:  # a copy: the block may run again (a loop), its values as read
            self._apply([], [], dict(axes), frame, line)

    def _fast_move(self, fast: dict[str, float], line: int) -> None:
        """The bulk of CAM output: X/Y/Z (and F) in G00/G01 (``fast`` holds no other letter);
        the same as _apply does for it, without its lists and checks of every other word."""
        start = self.w
        self.prev_end = start  # _move_to replaces self.w: this keeps the old one
        self.block_words = fast
        feed = self.feed
        if "F" in fast:
            if fast["F"] < 0:  # reported; the block moves at the feed it had
                self.error(line, _negative("F", fast["F"]))
            else:
                self.feed = feed = fast["F"]
                self.path.feed_rate(feed)
        if len(fast) == ("F" in fast):
            return  # no X, Y or Z word (the only other letters): no move
        rapid = self.motion == 0.0
        if self.absolute and self.feed_mode == 94 and (rapid or (feed and self.spindle_on)):
            # nothing to report and no time of its own: _target and _move_to written out for
            # absolute X/Y/Z
            work, machine, off = start[:], self.m[:], self.off
            for letter, axis in _AXIS_INDEX:
                given = fast.get(letter)
                if given is not None:
                    work[axis] = given
                    base = off[axis]
                    machine[axis] = None if base is None else given + base
            self.path.line(
                start, work, line, rapid=rapid, feed=None if rapid else feed, machine_end=machine
            )
            self.w, self.m = work, machine
            return
        work, machine = self._target(fast)
        self._move_to(work, machine, line, rapid)

    def _words(self, statement: Words, frame: _Frame, line: int) -> None:
        g: list[float] = []
        m: list[float] = []
        v: dict[str, float] = {}
        for letter, expr in statement.words:
            value = expr.value if type(expr) is Num else self.value(expr)
            if letter == "G":
                g.append(value)
                if type(expr) is not Num and (problem := self._code_problem("G", value)):
                    raise InputError(problem)
            elif letter == "M":
                m.append(value)
                if type(expr) is not Num and (problem := self._code_problem("M", value)):
                    raise InputError(problem)
            else:
                v[letter] = value
        self._apply(g, m, v, frame, line)

    def _apply(
        self, g: list[float], m: list[float], v: dict[str, float], frame: _Frame, line: int
    ) -> None:
        self.prev_end = self.w[:]
        self.block_words = v
        special = 0.0
        if g:
            special = self._g_codes(g, v, line)
        if self.bare and special != 4:  # a dwell reads its own words (_dwell_seconds)
            self._bare(v, line)
        if special == 65:
            self._call(frame, "g65", v, line)
            return
        for letter in ("F", "S"):
            if v.get(letter, 0) < 0:  # reported; the rest of the block goes on without it
                self.error(line, _negative(letter, v.pop(letter)))
        if "F" in v:
            self.feed = v["F"]
            self.path.feed_rate(self.feed)
        if "S" in v and not (self.lathe and special == 50):  # G50 S is the lathe's clamp
            if self.css is not None:
                self.css = v["S"]
            else:
                self.speed = v["S"]
                self.path.spindle_speed(self.speed)
        if "D" in v and not self.lathe:
            self.d_word = v["D"]
        if "T" in v and not self.iso:
            if self.lathe:  # T0101: turret station 1, offset 1; the turret turns at once
                tool = round(v["T"])
                self._tool_change(tool // 100 if tool >= 100 else tool, line)
            else:
                self.next_tool = round(v["T"])
        if m:
            for code in m:
                # M03/M04 (M13/M14 with coolant) start the spindle before the block's move
                if code in (3.0, 4.0, 13.0, 14.0):
                    self.spindle_on = True
                    self.stopped_cut_reported = False
        if self.lathe and special in codes.LATHE_CONTOUR:
            self._contour(frame, special, v, line)
        else:
            self._motion(special, v, line)
        if "T" in v and self.iso:
            self._tool_change(round(v["T"]), line)
        for code in m:
            self._m_code(code, frame, v, line)

    def _g_codes(self, g: list[float], v: dict[str, float], line: int) -> float:
        """Apply modal codes; return a non-modal code that decides this block's motion."""
        special = 0.0
        motion_codes = 0
        comp: float | None = None
        lathe = self.lathe
        for code in g:
            if code in codes.MOTION:
                self.motion = code
                self.cycle = None
                motion_codes += 1
            elif lathe and (done := self._lathe_code(code, v, line)) is not None:
                special = done or special
            elif code in (40, 41, 42):
                comp = code
            elif code in (43, 44, 43.4) and not self.iso and not lathe:
                self._length_offset(code, v, line)
            elif code in codes.CYCLES:
                self.cycle = _Cycle(code, initial=self.w[2])
                if self.iso:
                    self.warn_once(line, "iso-cycle", "ISO canned cycles are not drawn")
                    self.cycle = None
            elif code == 80:
                self.cycle = None
                self.rigid_tap = False
            elif code in (17, 18, 19):
                self.plane = (Plane.XY, Plane.ZX, Plane.YZ)[int(code) - 17]
            elif code in (20, 21) and not self.iso:
                self._units(Units.INCH if code == 20 else Units.MM, line)
            elif code in (70, 71) and self.iso:
                self._units(Units.INCH if code == 70 else Units.MM, line)
            elif code in (90, 91):
                self.absolute = code == 90
            elif code in (93, 94, 95):
                self.feed_mode = int(code)
            elif code in (98, 99) and not self.iso:
                self.cycle_return_r = code == 99
            elif (54 <= code <= 59 or 110 <= code <= 129) and code == int(code) and not self.iso:
                self.work_offset = code
                self._offsets()
            elif code in (154, 54.1) and not self.iso:
                # Haas G154 Pn and Fanuc G54.1 Pn: the additional work offsets (#7001 on)
                number = round(v.get("P", 1))
                top = 99 if code == 154 else 300
                if not 1 <= number <= top:
                    raise InputError(f"G{code:g} P{number}: work offsets are P1 to P{top}")
                self.work_offset = 109.0 + number if number <= 20 else 1000.0 + number
                self._offsets()
            elif code == 4 or (code in _SPECIAL and not self.iso):
                special = code
            elif code in codes.NOT_DRAWN_G and not self.iso:
                self.warn_once(line, f"G{code:g}", f"G{code:g} is not drawn by the dry run")
        if motion_codes > 1:
            self.error(line, "two motion codes (G00-G03) in one block")
        if comp is not None:
            self._compensation(comp, v, line)
        return special

    def _compensation(self, code: float, v: dict[str, float], line: int) -> None:
        """G41/G42 start and G40 cancel cutter compensation: on a straight move only (Fanuc
        alarm PS0034, Haas alarm on an arc), and G41/G42 with a D offset in force."""
        moves = any(k in v for k in "XYZIJKR")
        arc = self.motion in (2.0, 3.0) and self.cycle is None and moves
        if arc and code != self.comp:
            what = "cancel (G40)" if code == 40 else f"start (G{code:g})"
            self.error(line, f"cutter compensation {what} on an arc: it must be a straight move")
        if code != 40 and not self.lathe and not self.iso:
            offset = v.get("D", self.d_word)
            if offset is None or round(offset) == 0:
                self.error(line, f"G{code:g} without a cutter radius offset (D)")
        self.comp = code

    def _length_offset(self, code: float, v: dict[str, float], line: int) -> None:
        """G43/G44/G43.4 need a tool length offset H (in the block or in force)."""
        offset = v.get("H", self.h_word)
        if offset is None:
            self.error(line, f"G{code:g} without a tool length offset (H)")
            return
        self.h_word = offset
        if "H" in v and self.tool is not None and round(v["H"]) != self.tool:
            self.report(
                line,
                Severity.WARNING,
                f"G{code:g} H{round(v['H'])} with tool T{self.tool} in the spindle "
                "(length offset of another tool)",
            )

    def _lathe_code(self, code: float, v: dict[str, float], line: int) -> float | None:
        """A G code whose meaning on a lathe differs from a mill's; None: not one of them.
        Returns the block's non-modal code (or 0.0)."""
        if code in (98.0, 99.0):  # feed per minute / per revolution (G-code system A)
            self.feed_mode = 94 if code == 98 else 95
        elif code == 96:  # constant surface speed: S is metres (feet) per minute
            self.css = v.get("S", self.css or 0.0)
        elif code == 97:  # spindle speed in rpm
            self.css = None
        elif code == 50:
            if "S" in v:
                self.max_rpm = v["S"]
            if any(k in v for k in "XZUW"):
                return 92.0  # sets the coordinates, as G92 does on a mill
        elif code in codes.LATHE_CONTOUR:
            return code
        elif code in codes.LATHE_NOT_DRAWN:
            self.warn_once(line, f"G{code:g}", f"G{code:g} is not drawn by the dry run")
            if code in (90.0, 92.0, 94.0):
                self.motion = code  # modal single cycles (group 01)
                self.cycle = None
            else:
                return code  # G74-G76: X/Z are the cycle's end point; the tool comes back
        elif code == 32:
            self.motion = 1.0  # threading: a straight feed move at F per revolution (lead)
            self.cycle = None
        elif code in codes.LATHE_CYCLES:
            self.cycle = _Cycle(code, initial=self.w[2])
        else:
            return None
        return 0.0

    def _bare(self, v: dict[str, float], line: int) -> None:
        """Words written without a decimal point count in the least input increment on
        Haas and Fanuc (``X100`` is 0.1 mm, 0.01 inch): docs/check.md#decimal-point."""
        for letter, value in v.items():
            if type(value) is int and value and letter in self.bare:
                step, unit = (0.0001, "inch") if self.units is Units.INCH else (0.001, "mm")
                v[letter] = scaled = value * step
                self.warn_once(
                    line,
                    "bare",
                    f"{letter}{value} has no decimal point: the {self.dialect.title} control "
                    f"reads it as {letter}{scaled:g} (whole numbers count in {step:g} {unit}); "
                    f"write {letter}{value}. for {value} {unit}",
                )

    def _dwell_seconds(self, v: dict[str, float]) -> float:
        """G04's time: P without a decimal point in milliseconds, with one in seconds (Haas,
        Fanuc); X (a lathe's U) in seconds, without a point in milliseconds where whole
        numbers count in the increment (Fanuc: the dwell's increment is 1 ms)."""
        if "P" in v:
            p = v["P"]
            return p / 1000.0 if self.dialect.dwell_ms and type(p) is int else p
        letter = "U" if self.lathe and "X" not in v and "U" in v else "X"
        x = v.get(letter, 0.0)
        return x / 1000.0 if type(x) is int and letter in self.bare else x

    def _units(self, units: Units, line: int) -> None:
        if self.units is not None and units is not self.units:
            self.warn_once(line, "units", "the program changes units (G20/G21) part way")
        self.units = units
        if not (self.machine and self.machine.rapid_rate):
            self.path.rapid_rate = rapid_rate(units)
        self._convert_machine_units(units)
        self._offsets()

    def _convert_machine_units(self, units: Units) -> None:
        """Travel and configured offsets in the machine's units -> the program's (once)."""
        machine = self.machine
        if self.converted or machine is None or machine.travel_units is None:
            return
        self.converted = True
        if machine.travel_units is units:
            return
        factor = 25.4 if units is Units.MM else 1 / 25.4
        self.path.scale_travel(factor)
        if machine.rapid_rate:  # given in the travel's units too
            self.path.rapid_rate = machine.rapid_rate * factor
        for number, value in self.configured.items():
            if self.globals.get(number) == value:  # not set by the program since
                self.globals[number] = value * factor

    # ------------------------------------------------------------------ motion
    def _target(self, v: dict[str, float]) -> tuple[list[float | None], list[float | None]]:
        if self.lathe:
            return self._lathe_target(v)
        w, m = self.w[:], self.m[:]
        for axis, letter in enumerate(_AXES):
            if letter in v:
                value = v[letter]
                if self.absolute:
                    w[axis] = value
                    off = self.off[axis]
                    m[axis] = None if off is None else value + off
                else:
                    current = w[axis]
                    w[axis] = None if current is None else current + value
                    machine = m[axis]
                    m[axis] = None if machine is None else machine + value
        return w, m

    def _lathe_target(self, v: dict[str, float]) -> tuple[list[float | None], list[float | None]]:
        """A lathe's end point: X is a diameter (the dry run keeps the radius, so arcs' I and R
        agree with it), U/V/W are incremental X/Y/Z (G-code system A: no G90/G91)."""
        w, m = self.w[:], self.m[:]
        for axis, (letter, step) in enumerate((("X", "U"), ("Y", "V"), ("Z", "W"))):
            half = 0.5 if axis == 0 else 1.0
            if letter in v:
                value = v[letter] * half
                w[axis] = value
                off = self.off[axis]
                m[axis] = None if off is None else value + off
            elif step in v:
                delta = v[step] * half
                current, machine = w[axis], m[axis]
                w[axis] = None if current is None else current + delta
                m[axis] = None if machine is None else machine + delta
        return w, m

    def _motion(self, special: float, v: dict[str, float], line: int) -> None:
        has_axes = "X" in v or "Y" in v or "Z" in v
        if special:
            if special == 4:
                self.path.dwell(self._dwell_seconds(v) if not self.iso else v.get("F", 0.0))
            elif special == 28:
                self._home(v, line)
            elif special == 53:
                self._machine_move(v, line)
            elif special == 10:
                self._g10(v, line)
            elif special == 52:
                for axis, letter in enumerate(_AXES):
                    if letter in v:
                        self.globals[5201 + axis] = v[letter]
                self._offsets()
            elif special in _PROBE_MOVES:
                # a probe or tool-setter move (skip): the spindle is stopped on purpose
                work, machine = self._target(v)
                running, self.spindle_on = self.spindle_on, True
                self._move_to(work, machine, line, rapid=False)
                self.spindle_on = running
            elif special == 92:
                w, _m = self._target(v)
                for axis, letter in enumerate(_AXES):
                    if letter in v:
                        self.w[axis] = w[axis]
                        self.m[axis] = None
                self.warn_once(
                    line, "G92", "G92 shifts the coordinates: machine travel not checked"
                )
            return
        if self.iso and not has_axes and "R" not in v and any(k in v for k in "IJK"):
            self._iso_centre(v)  # "N100 I+20 J+60 *": a circle centre (pole) of its own
            return
        if self.cycle is not None:
            if has_axes or "R" in v or "L" in v:
                self._holes(v, line)
            return
        motion = self.motion
        if self.lathe:
            has_axes = has_axes or "U" in v or "W" in v
        if motion == 0 or motion == 1:
            if has_axes:
                self._linear(v, line, rapid=motion == 0)
        elif motion in (2.0, 3.0) and (has_axes or any(k in v for k in "IJKR")):
            self._arc(v, line, clockwise=motion == 2)

    def _iso_centre(self, v: dict[str, float]) -> None:
        """Heidenhain ISO I/J/K: the circle centre, absolute (G90) or from the position (G91)."""
        for axis, letter in enumerate("IJK"):
            if letter in v:
                base = self.w[axis]
                if self.absolute:
                    self.iso_centre[letter] = v[letter]
                elif base is not None:
                    self.iso_centre[letter] = base + v[letter]

    def _move_to(
        self, w: list[float | None], m: list[float | None], line: int, rapid: bool
    ) -> None:
        seconds = None
        if not rapid:
            seconds = self._feed_seconds(line, w[2])
        self.path.line(
            (self.w[0], self.w[1], self.w[2]),
            (w[0], w[1], w[2]),
            line,
            rapid=rapid,
            feed=None if rapid else self._feed_rate(),
            machine_end=m,
        )
        if seconds is not None and self.feed_mode == 93:
            self.path.dwell(seconds)
        self.w, self.m = w, m

    def _feed_rate(self) -> float | None:
        if self.feed_mode == 95 and self.feed is not None:
            rpm = self._rpm()
            return self.feed * rpm if rpm else None
        return self.feed if self.feed_mode == 94 else None

    def _rpm(self) -> float:
        """Spindle speed now: S, or under G96 the surface speed at the tool's radius (X),
        clamped by G50 S (or a default clamp: Ours)."""
        if self.css is None:
            return self.speed
        clamp = self.max_rpm or _LATHE_MAX_RPM
        radius = abs(self.w[0]) if self.w[0] is not None else 0.0
        if radius < 1e-6:
            return clamp
        per_unit = 12.0 if self.units is Units.INCH else 1000.0  # ft or m per minute
        return min(clamp, self.css * per_unit / (2 * math.pi * radius))

    def _feed_seconds(self, line: int, end_z: float | None = None) -> float | None:
        if not self.feed and not self.no_feed_reported:
            self.no_feed_reported = True
            self.error(line, "a feed move with no feed rate (F) in force")
        if not self.spindle_on:
            self._stopped_feed(line, end_z)
        if self.feed_mode == 93 and self.feed:
            return 60.0 / self.feed  # inverse time: the move takes 1/F minutes
        return None

    def _stopped_feed(self, line: int, end_z: float | None) -> None:
        """A feed move with the spindle stopped: an error below Z0 (the top of the stock, or a
        lathe part's face: the tool cuts), else a warning (it may be in the air)."""
        start_z = self.w[2]
        tol = 0.0005 if self.units is Units.INCH else 0.01
        below = (start_z is not None and start_z < -tol) or (end_z is not None and end_z < -tol)
        if not below:
            self.warn_once(line, "spindle", "a feed move with the spindle stopped")
            return
        if self.stopped_cut_reported:
            return  # once until the spindle starts again
        self.stopped_cut_reported = True
        cause = ""
        if self.spindle_stop is not None:
            what, where = self.spindle_stop
            cause = f" ({what} at line {where} stopped it)"
        self.error(line, f"a feed move below Z0 with the spindle stopped{cause}")

    def _linear(self, v: dict[str, float], line: int, *, rapid: bool) -> None:
        w, m = self._target(v)
        self._move_to(w, m, line, rapid)

    def _arc(self, v: dict[str, float], line: int, *, clockwise: bool) -> None:
        w, m = self._target(v)
        self._feed_seconds(line, w[2])
        a, b, c = {Plane.XY: (0, 1, 2), Plane.ZX: (2, 0, 1), Plane.YZ: (1, 2, 0)}[self.plane]
        start = self.w
        sa, sb, ea, eb = start[a], start[b], w[a], w[b]
        if sa is None or sb is None or ea is None or eb is None or start[c] is None:
            self.warn_once(line, "arc-unknown", "an arc from an unknown position is not drawn")
            self.w, self.m = w, m
            return
        tol = 0.0005 if self.units is Units.INCH else 0.01
        letters = ("I", "J", "K")
        if "R" in v:
            radius = v["R"]
            chord = math.hypot(ea - sa, eb - sb)
            if chord < 1e-9:
                self.report(
                    line,
                    Severity.WARNING,
                    "an arc given by R with the same start and end point does not move",
                )
                return
            too_small = short_radius(radius, chord, tol)
            if too_small is not None:
                self.error(line, f"arc radius {too_small}")
                self.w, self.m = w, m  # the run goes on from where the arc was meant to end
                return
            ca, cb = radius_arc_center((sa, sb), (ea, eb), chord, radius, ccw=not clockwise)
        else:
            ka, kb = letters[a], letters[b]
            if self.iso:
                self._iso_centre(v)
                v = {**v, **self.iso_centre}
            if ka not in v and kb not in v:
                self.error(
                    line, f"G0{2 if clockwise else 3} without its centre ({ka}/{kb}) or radius (R)"
                )
                self.w, self.m = w, m
                return
            if self.iso:  # Heidenhain ISO: I, J, K are the absolute circle centre
                ca, cb = v.get(ka, sa), v.get(kb, sb)
            else:
                ca, cb = sa + v.get(ka, 0.0), sb + v.get(kb, 0.0)
            r0 = math.hypot(sa - ca, sb - cb)
            r1 = math.hypot(ea - ca, eb - cb)
            if abs(r0 - r1) > tol:
                self.error(
                    line,
                    f"arc end is not on its circle: start radius {r0:.4f}, end radius "
                    f"{r1:.4f} (differ by {abs(r0 - r1):.4f})",
                )
                self.w, self.m = w, m
                return
        center = [0.0, 0.0, 0.0]
        center[a], center[b] = ca, cb
        startp = (float(start[0] or 0.0), float(start[1] or 0.0), float(start[2] or 0.0))
        endp = (
            float(w[0] if w[0] is not None else startp[0]),
            float(w[1] if w[1] is not None else startp[1]),
            float(w[2] if w[2] is not None else startp[2]),
        )
        center[c] = startp[c]
        shift = tuple(
            None if mm is None or ww is None else mm - ww for mm, ww in zip(m, w, strict=True)
        )
        self.path.arc(
            startp, endp, (center[0], center[1], center[2]), self.plane, line,
            clockwise=clockwise, feed=self._feed_rate(), machine_shift=shift,
        )  # fmt: skip
        self.w, self.m = w, m

    def _home(self, v: dict[str, float], line: int) -> None:
        """G28: through the given point, then the named axes to machine zero (all if none)."""
        letters = ("XU", "YV", "ZW") if self.lathe else _AXES
        named = [axis for axis, names in enumerate(letters) if any(k in v for k in names)]
        if named:
            w, m = self._target(v)
            self._move_to(w, m, line, rapid=True)
        else:
            named = [0, 1, 2]
        w, m = self.w[:], self.m[:]
        for axis in named:
            m[axis] = 0.0
            off = self.off[axis]
            w[axis] = None if off is None else -off
        self._move_to(w, m, line, rapid=True)

    def _machine_move(self, v: dict[str, float], line: int) -> None:
        """G53: the named axes to machine coordinates, at rapid (non-modal)."""
        w, m = self.w[:], self.m[:]
        for axis, letter in enumerate(_AXES):
            if letter in v:
                value = v[letter] / 2 if self.lathe and axis == 0 else v[letter]  # diameter
                m[axis] = value
                off = self.off[axis]
                w[axis] = None if off is None else value - off
        self._move_to(w, m, line, rapid=True)

    def _g10(self, v: dict[str, float], line: int) -> None:
        kind = round(v.get("L", 0))
        number = round(v.get("P", 0))
        if kind == 2 and 0 <= number <= 6:
            code = 52.0 if number == 0 else 53.0 + number
        elif kind == 20 and 1 <= number <= 99:
            code = 109.0 + number if number <= 20 else 1000.0 + number
        else:
            return  # tool offsets (L1, L10, L11...) do not change the path
        base = _work_base(code)
        if base is None:
            return
        for axis, letter in enumerate(_AXES):
            if letter in v:
                old = self.globals.get(base + axis, 0.0)
                self.globals[base + axis] = v[letter] if self.absolute else old + v[letter]
        self._offsets()

    def _holes(self, v: dict[str, float], line: int) -> None:
        cycle = self.cycle
        assert cycle is not None
        initial = cycle.initial if cycle.initial is not None else self.w[2]
        if "R" in v:
            cycle.r = v["R"] if self.absolute or initial is None else initial + v["R"]
        if "Z" in v:
            base = cycle.r if cycle.r is not None else initial
            cycle.z = v["Z"] if self.absolute or base is None else base + v["Z"]
        if "P" in v:
            dwell = v["P"]
            bare = self.dialect.dwell_ms and type(dwell) is int
            cycle.dwell = dwell / 1000.0 if bare else dwell
        if cycle.z is None:
            self.error(line, f"canned cycle G{cycle.code:g} without a depth (Z)")
            return
        if not cycle.peck_checked:
            cycle.peck_checked = True
            self._cycle_words(cycle, v, line)
        repeats = round(v.get("L", v.get("K", 1)))
        xy: dict[str, float] = {k: v[k] for k in ("X", "Y") if k in v}
        r_plane = cycle.r if cycle.r is not None else initial
        starts = self.rigid_tap or self.dialect.tap_starts_spindle
        rigid = cycle.code == 84 and starts and not self.spindle_on
        if rigid:
            # the cycle turns the spindle itself: Fanuc rigid tapping (M29), any Haas G84
            self.spindle_on = True
        for _ in range(max(0, min(repeats, 10_000))):
            w, m = self._target(xy)
            self._move_to(w, m, line, rapid=True)
            if r_plane is not None:
                self._to_z(r_plane, line, rapid=True)
            self._to_z(cycle.z, line, rapid=False)
            self.path.dwell(cycle.dwell)
            back = r_plane if self.cycle_return_r or initial is None else initial
            if back is not None:
                self._to_z(back, line, rapid=cycle.code not in codes.FEED_RETRACT)
        if rigid:
            self.spindle_on = False

    def _cycle_words(self, cycle: _Cycle, v: dict[str, float], line: int) -> None:
        """What a cycle needs before its first hole (the control alarms without it)."""
        # a mill's peck cycles need the peck depth Q (Fanuc alarm PS0045; a Haas takes I/J/K
        # instead); a lathe's G83 without Q drills in one go
        haas_pecks = self.dialect.haas and "I" in v
        if cycle.code in (73.0, 83.0) and not self.lathe and "Q" not in v and not haas_pecks:
            self.error(line, f"G{cycle.code:g} without a peck depth (Q)")
        starts = self.rigid_tap or self.dialect.tap_starts_spindle
        if cycle.code == 84 and not self.spindle_on and not starts:
            self.error(line, "a tap (G84) with the spindle stopped")
            self.stopped_cut_reported = True  # the same fault: not again for its holes

    def _to_z(self, z: float, line: int, *, rapid: bool) -> None:
        w, m = self.w[:], self.m[:]
        w[2] = z
        off = self.off[2]
        m[2] = None if off is None else z + off
        self._move_to(w, m, line, rapid)

    # ------------------------------------------------------------------ M codes, tools, calls
    def _m_code(self, value: float, frame: _Frame, v: dict[str, float], line: int) -> None:
        code = round(value)
        if code in self.dialect.spindle_stops and not (self.iso or self.lathe):
            # M05, and M06: the tool change orients and stops the spindle (Haas, Fanuc)
            if self.spindle_on:
                self.spindle_stop = (f"M{code:02d}", line)
            self.spindle_on = False
        if code == 6 and not self.iso:
            if self.next_tool is None:
                self.report(line, Severity.WARNING, "M06 with no tool selected (T)")
                return
            self._tool_change(self.next_tool, line)
        elif code in (3, 4, 13, 14):
            pass  # started before the block's move (_apply)
        elif code == 5:
            if self.spindle_on:
                self.spindle_stop = ("M05", line)
            self.spindle_on = False
        elif code == self.dialect.rigid_tap_m and not self.iso:
            self.rigid_tap = True  # Fanuc M29 S..: the next G84 is a rigid tap
        elif code in (30, 2):
            if code == 30:
                self.counters = [self.counters[0] + 1, self.counters[1] + 1]
            self.ended = True
            raise _Stop
        elif code == 99 and not self.iso:
            if frame.kind == "main":
                self.ended = True  # M99 in a main program: the control starts it again
                raise _Stop
            self._return(frame, line, v.get("P"))
        elif code == 97 and not self.iso:
            self._call(frame, "m97", v, line)
        elif code == 98 and not self.iso:
            self._call(frame, "m98", v, line)

    def _tool_change(self, tool: int, line: int) -> None:
        self.tool = tool
        known = self.machine.tools if self.machine is not None else None
        if known is not None and str(tool) not in known and tool != 0:
            self.error(line, f"tool T{tool} is not in the tool table of {self.machine_name()}")
        if tool != 0:
            # S and F of the changing block are the new tool's; the ones before it belong to
            # the tool before (the first S and F after the change are taken as they come)
            block = self.block_words
            self.path.change_tool(
                str(tool), line, speed=block.get("S") or None, feed=block.get("F")
            )

    def machine_name(self) -> str:
        return (self.machine.name if self.machine else "") or "the machine"

    def _contour(self, frame: _Frame, code: float, v: dict[str, float], line: int) -> None:
        """Lathe G70-G73 P.. Q..: the blocks Np..Nq are the contour. The roughing cycles
        (G71-G73) run it once, drawn as the finished contour (Ours: the roughing passes are
        not drawn), and the program goes on after Nq; G70 runs it and goes on after itself."""
        if "P" not in v or "Q" not in v:
            return  # the first block of the two-block form (G71 U.. R..): depth and retract
        program = frame.program
        first, last = round(v["P"]), round(v["Q"])
        start, end = self._number(program, first), self._number(program, last)
        if start is None or end is None:
            missing = first if start is None else last
            raise InputError(f"G{code:g}: no block N{missing} in {program.name} (P{first} Q{last})")
        if end < start:
            raise InputError(f"G{code:g}: N{last} (Q) comes before N{first} (P)")
        if code != 70:
            self.warn_once(line, "lathe-roughing", "lathe roughing cycles are drawn as their "
                           "finished contour")  # fmt: skip
            frame.pc = max(frame.pc, end + 1)
        if len(self.frames) > _MAX_NESTING:
            self.error(line, f"sub-program calls nest deeper than {_MAX_NESTING} levels")
            return
        call_line = frame.call_line if frame.kind != "main" else line
        self.frames.append(
            _Frame(program, start, self.locals, "cycle", call_line, start=start, stop=end)
        )

    def _call(self, frame: _Frame, kind: str, v: dict[str, float], line: int) -> None:
        if "P" not in v:
            self.error(line, f"{kind.upper()} without a program or block number (P)")
            return
        number = round(v["P"])
        repeats = round(v.get("L", 1))
        if repeats < 1:
            return
        if len(self.frames) > _MAX_NESTING:
            self.error(line, f"sub-program calls nest deeper than {_MAX_NESTING} levels")
            return
        call_line = frame.call_line if frame.kind != "main" else line
        if kind == "m97":
            index = self._number(frame.program, number)
            if index is None:
                raise InputError(f"M97 P{number}: no block N{number} in {frame.program.name}")
            program = frame.program
        else:
            found = self._find(number, line)
            if found is None:
                # what the missing program does is not known: it may start the spindle (a
                # shop's tool change macro), so a cut after it is not reported as one with
                # the spindle stopped (the call is a warning already)
                self.spindle_on = True
                self.stopped_cut_reported = False
                return
            program, index = found, 0
        if kind == "g65":
            new_locals = {_ARGUMENTS[k]: value for k, value in v.items() if k in _ARGUMENTS}
        else:
            new_locals = self.locals
        self.frames.append(_Frame(program, index, new_locals, kind, call_line, repeats, index))
        self.locals = new_locals

    def _find(self, number: int, line: int) -> _Program | None:
        program = self.programs.get(number)
        while program is None and not self.scan_done:  # a sub-program further on in the file
            more = self._advance()
            program = self.programs.get(number)
            if not more:
                break
        if program is not None:
            return program
        name = f"O{number:05d}"
        if number in self.missing:
            return None  # reported at its first call: one warning per missing program
        text = None
        if self.library is not None:
            try:
                text = self.library(name)
            except Exception:  # a library callback must not break the dry run
                text = None
        if text is None:
            self.missing.add(number)  # asked once: a loop of calls does not ask again
            self.report(line, Severity.WARNING, f"calls {name}, which is not in the library")
            return None
        # the called program is read with the caller's dialect (a lathe sub of a lathe job)
        body = _Run(
            TextSource(text),
            self.control,
            name,
            MachineLimits(dialect=self.dialect.name),
            None,
            self.budget,
        )
        for problem in body.problems.values():
            self.report(line, problem.severity, f"in {name} line {problem.line}: {problem.message}")
        body._finish_scan()  # its every block checked, as a program of this file is
        program = replace(body.main, name=name, number=number, external=True)
        self.programs[number] = program
        return program

    def _return(self, frame: _Frame, line: int, to_block: float | None = None) -> None:
        if frame.repeat > 1:
            frame.repeat -= 1
            frame.pc = frame.start
            self._jump(line)
            return
        self.frames.pop()
        caller = self.frames[-1]
        self.locals = caller.locals
        if to_block is not None:
            found = self._number(caller.program, round(to_block))
            if found is None:
                raise InputError(f"M99 P{round(to_block)}: no block N{round(to_block)}")
            caller.pc = found

    # ------------------------------------------------------------------ result
    def result(self) -> CheckResult:
        problems, more = _capped(list(self.problems.values()))
        if self.machine is not None:
            problems += self.path.travel_problems(self.machine.name)
            number = self.main.number
            for low, high in self.machine.protected:
                if number is not None and low <= number <= high:
                    problems.append(
                        Problem(
                            max(1, self.main.first_line - 1) if self.main.count else 1,
                            Severity.ERROR,
                            f"O{number:05d} is a protected program number on "
                            f"{self.machine_name()} (O{low:05d}-O{high:05d} hold the "
                            "control's own macros)",
                        )
                    )
        unknown = [a for a, low in zip(_AXES, self.path.low, strict=True) if low == math.inf]
        if unknown == ["Y"] and self.path.unplaced and not (self.path.rapid or self.path.feed):
            # X and Z but never Y: a lathe program read as a mill program measures and draws
            # nothing; say so rather than report 0 moves silently
            problems.append(
                Problem(
                    self.path.unplaced_line,
                    Severity.WARNING,
                    f"{self.path.unplaced} feed moves are not measured or drawn: the program never "
                    f"gives the {'/'.join(unknown)} position",
                )
            )
        result = self.path.result(
            self.control,
            self.name,
            problems,
            units=self.units,
            blocks=self.blocks_run,
            end=EndState(
                position={a: v for a, v in zip(_AXES, self.w, strict=True) if v is not None},
                machine_position={
                    a: v for a, v in zip(_AXES, self.m, strict=True) if v is not None
                },
                tool=str(self.tool) if self.tool is not None else None,
                variables={
                    **self.globals,
                    **self.main_locals,
                    3901: float(self.counters[0]),  # parts counted by this run (from 0)
                    3902: float(self.counters[1]),
                },
                ended=self.ended,
            ),
        )
        result = replace(
            result,
            more_problems=len(more),
            more_errors=sum(p.severity is Severity.ERROR for p in more),
        )
        return result if self.iso else replace(result, dialect=self.dialect.name)


def _capped(problems: list[Problem]) -> tuple[list[Problem], list[Problem]]:
    """The first :data:`MAX_PROBLEMS` problems by line, and the rest (counted, not listed)."""
    if len(problems) <= MAX_PROBLEMS:
        return problems, []
    problems.sort(key=lambda p: p.line)
    return problems[:MAX_PROBLEMS], problems[MAX_PROBLEMS:]


def _only_comments(lines: list[tuple[int, int, str]]) -> bool:
    return all(_COMMENT_ONLY.match(text) for _, _, text in lines)


def _work_base(code: float) -> int | None:
    """First variable of work offset ``code`` (G54..G59, G110..G129, G154 P21..P99)."""
    if 54 <= code <= 59:
        return 5221 + 20 * (int(code) - 54)
    if code == 53:
        return None
    if 110 <= code <= 129:
        return 7001 + 20 * (int(code) - 110)
    if 1021 <= code <= 1099:
        return 14001 + 20 * (int(code) - 1001)
    return None


def _offset_base(key: str) -> int | None:
    name = offset_key(key)
    if name.startswith("G154 P"):
        return _work_base(1000.0 + int(name[6:]))
    try:
        return _work_base(float(name[1:]))
    except ValueError:
        return None


def run_gcode(
    source: Source,
    *,
    control: Control,
    name: str,
    machine: MachineLimits | None,
    library: Library | None,
    budget: Budget,
) -> CheckResult:
    """Dry-run a G-code program (see the module docstring)."""
    run = _Run(source, control, name, machine, library, budget)
    run.run()
    run._finish_scan()
    return run.result()
