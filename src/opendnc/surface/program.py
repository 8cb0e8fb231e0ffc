"""Generate the Haas program that probes a grid and prints one DPRNT line per point.

At every point the program runs the WIPS single-surface Z cycle (``G65 P9995 W54. A20. H..``),
which writes the touched Z into the G54 Z offset ``#5223`` (docs/surface.md). The program
saves the original G54 Z first, turns each reading into a height in the original G54
(``#5223 - saved``), puts G54 Z back at once (so every move, and a run stopped half way,
keeps the operator's offset), and prints::

    P    12 X   1.5000 Y   0.5000 Z  -0.0012

``P`` is the point number in serpentine order; X and Y are the control's own work position
(#5041/#5042), so the capture can tell a missing line from a shifted one. Lines
``SURFACE START ...`` and ``SURFACE END`` bracket the run.

Safety choices: probe on (P9832) once and off (P9833) at the end, protected positioning
(P9810) for every move near the part, rapid moves only at the clearance height, G103 P1 so
the control does not read #5223 ahead of the probe cycle that writes it, and 8000/9000
series program numbers refused (the control keeps its own probing routines there).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from opendnc.errors import InputError
from opendnc.surface.grid import Grid, Units

SAVED_Z = 140
"""Global variable holding the operator's G54 Z for the whole run."""
POINT_VAR = 141
"""Global variable holding the number of the point being probed."""
HEIGHT_VAR = 142
"""Global variable holding the measured height of the point in the original G54."""

RESERVED_SERIES = (8000, 9000)
"""Program number blocks a Haas keeps for its own (probing) macros."""


def parse_program_number(text: str | int) -> int:
    """``O01234``, ``O1234`` or ``1234`` -> 1234; refuse 0, > 99999 and the 8000/9000 series."""
    if isinstance(text, int):
        number = text
    else:
        match = re.fullmatch(r"\s*[Oo]?(\d{1,5})\s*", text)
        if match is None:
            raise InputError(f"bad program number {text!r}: use O followed by 1 to 5 digits")
        number = int(match.group(1))
    if not 1 <= number <= 99999:
        raise InputError(f"program number O{number:05d} out of range O00001..O99999")
    for series in RESERVED_SERIES:
        if series <= number < series + 1000:
            raise InputError(
                f"program number O{number:05d} refused: the {series} series holds the "
                "control's own probing routines (choose another number)"
            )
    return number


@dataclass(frozen=True)
class ProbeMoves:
    """Heights (work Z, program units) and feed of the probing moves."""

    clearance: float
    approach: float
    depth: float
    feed: float

    @property
    def search(self) -> float:
        """Search distance the probe may travel down from ``approach`` (the WIPS ``H``)."""
        return self.approach + self.depth


def default_moves(units: Units, clearance: float | None = None) -> ProbeMoves:
    """Conservative defaults: clearance 1 in / 25 mm, approach 0.1 in / 2.5 mm, depth same."""
    if units is Units.INCH:
        return ProbeMoves(1.0 if clearance is None else clearance, 0.1, 0.1, 30.0)
    return ProbeMoves(25.0 if clearance is None else clearance, 2.5, 2.5, 750.0)


def check_moves(moves: ProbeMoves) -> None:
    """Refuse heights and feeds that cannot be right, with the reason."""
    for name, value in (
        ("clearance", moves.clearance),
        ("approach", moves.approach),
        ("depth", moves.depth),
        ("feed", moves.feed),
    ):
        if not math.isfinite(value):
            raise InputError(f"{name} must be a finite number")
    if moves.clearance <= moves.approach:
        raise InputError(
            f"clearance Z{moves.clearance:g} must be above approach Z{moves.approach:g}"
        )
    if moves.approach <= 0:
        raise InputError(f"approach Z{moves.approach:g} must be above the surface (Z0)")
    if moves.depth <= 0:
        raise InputError(f"depth {moves.depth:g} must be positive (search below Z0)")
    if moves.feed <= 0:
        raise InputError(f"feed F{moves.feed:g} must be positive")


def _num(value: float, places: int) -> str:
    """A Haas coordinate word value: ``1.5000``, ``-0.2500``, ``0.``-style never needed."""
    text = f"{value:.{places}f}"
    return "0." + "0" * places if text.startswith("-") and float(text) == 0 else text


@dataclass(frozen=True)
class SurfaceProgram:
    """A generated program and what it probes."""

    number: int
    grid: Grid
    moves: ProbeMoves
    text: str

    @property
    def name(self) -> str:
        """``O01234``."""
        return f"O{self.number:05d}"


def generate(
    grid: Grid,
    *,
    number: int = 1234,
    moves: ProbeMoves | None = None,
    work_offset: int = 54,
    tool: int | None = None,
) -> SurfaceProgram:
    """Build the probing program for ``grid`` (see the module docstring for its layout)."""
    number = parse_program_number(number)
    moves = moves or default_moves(grid.units)
    check_moves(moves)
    if work_offset != 54:
        raise InputError("only G54 is supported: the program reads and restores #5223 (G54 Z)")
    if tool is not None and not 1 <= tool <= 200:
        raise InputError(f"tool T{tool} out of range 1..200")
    units = grid.units
    d = units.decimals
    fmt = f"{4}{d}" if units is Units.INCH else f"{5}{d}"  # [44] inch, [53] mm
    pwidth = len(str(grid.size))
    unit = "IN" if units is Units.INCH else "MM"
    feed = _num(moves.feed, 1)
    clear, approach = _num(moves.clearance, d), _num(moves.approach, d)
    lines = [
        "%",
        f"O{number:05d} (OPENDNC SURFACE MAP {grid.columns} X {grid.rows})",
        f"(GRID {grid.columns} X {grid.rows} = {grid.size} POINTS, SERPENTINE ORDER)",
        f"(PITCH X {_num(grid.pitch_x, d)} Y {_num(grid.pitch_y, d)} {unit}, "
        f"ORIGIN X {_num(grid.origin_x, d)} Y {_num(grid.origin_y, d)})",
        f"(CLEARANCE Z {clear}, APPROACH Z {approach}, SEARCH {_num(moves.search, d)} {unit})",
        "(BEFORE CYCLE START: PROBE LOADED AND CALIBRATED, G54 X Y ON THE GRID ORIGIN SIDE,)",
        "(G54 Z ZERO NEAR THE SURFACE, AREA CLEAR, DPRNT OUTPUT SET UP, SINGLE BLOCK FIRST RUN)",
        "(USES GLOBALS #140 SAVED G54 Z, #141 POINT, #142 HEIGHT)",
        "(--- SAFETY HEADER ---)",
        f"{units.g_code} ({'INCH' if units is Units.INCH else 'METRIC'} UNITS)",
        "G00 G17 G40 G49 G80 G90 (CANCEL COMP AND CYCLES, ABSOLUTE)",
        "G54 (WORK OFFSET)",
        "G103 P1 (LOOK AHEAD ONE BLOCK: READ #5223 ONLY AFTER THE PROBE WROTE IT)",
    ]
    if tool is not None:
        lines += [f"T{tool} M06 (LOAD THE PROBE)", f"G43 H{tool} Z{clear} (LENGTH OFFSET, CLEAR)"]
    lines += [
        f"G00 G90 Z{clear} (GO TO CLEARANCE)",
        f"#{SAVED_Z} = #5223 (SAVE THE G54 Z OFFSET)",
        "G65 P9832 (PROBE ON)",
        f"DPRNT[SURFACE*START*ZOFFSET#{SAVED_Z}[{fmt}]]",
    ]
    for point in grid.points:
        lines += [
            f"(POINT {point.number} ROW {point.row} COL {point.col})",
            f"G00 X{_num(point.x, d)} Y{_num(point.y, d)} (RAPID AT CLEARANCE)",
            f"G65 P9810 Z{approach} F{feed} (PROTECTED MOVE DOWN)",
            f"#{POINT_VAR} = {point.number}",
            f"G65 P9995 W54. A20. H-{_num(moves.search, d)} (SINGLE SURFACE Z, WRITES #5223)",
            f"#{HEIGHT_VAR} = #5223 - #{SAVED_Z} (HEIGHT IN THE ORIGINAL G54)",
            f"#5223 = #{SAVED_Z} (RESTORE G54 Z)",
            f"DPRNT[P#{POINT_VAR}[{pwidth}0]*X#5041[{fmt}]*Y#5042[{fmt}]*Z#{HEIGHT_VAR}[{fmt}]]",
            f"G65 P9810 Z{clear} F{feed} (PROTECTED RETRACT)",
        ]
    lines += [
        "(--- SAFETY FOOTER ---)",
        f"G00 Z{clear} (CLEARANCE)",
        f"#5223 = #{SAVED_Z} (G54 Z AS IT WAS)",
        "G65 P9833 (PROBE OFF)",
        "DPRNT[SURFACE*END]",
        "G103 (LOOK AHEAD BACK TO NORMAL)",
        "G00 G53 Z0. (RETRACT TO MACHINE Z HOME)",
        "M30",
        "%",
    ]
    return SurfaceProgram(number, grid, moves, "\n".join(lines) + "\n")


_HEADER_GRID = re.compile(r"\(GRID (\d+) X (\d+) =")
_HEADER_PITCH = re.compile(
    r"\(PITCH X (\S+) Y (\S+) (IN|MM), ORIGIN X (\S+) Y (\S+)\)", re.IGNORECASE
)


def grid_from_program(text: str) -> Grid:
    """The grid a program made by :func:`generate` probes (read from its header comments)."""
    grid_match = _HEADER_GRID.search(text)
    pitch_match = _HEADER_PITCH.search(text)
    if grid_match is None or pitch_match is None:
        raise InputError("not an opendnc surface program: no (GRID ...) and (PITCH ...) header")
    try:
        px, py, ox, oy = (float(pitch_match.group(i)) for i in (1, 2, 4, 5))
    except ValueError:
        raise InputError(f"bad surface program header {pitch_match.group(0)!r}") from None
    units = Units.INCH if pitch_match.group(3).upper() == "IN" else Units.MM
    return Grid(int(grid_match.group(1)), int(grid_match.group(2)), px, py, ox, oy, units)
