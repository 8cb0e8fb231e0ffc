"""What a dry run reports: problems, tools, moves, extents, distances and an estimated time.

Plain frozen dataclasses and enums (no I/O). :meth:`CheckResult.to_json` gives the JSON the
command line prints with ``--json`` and the web preview reads (docs/check.md#json).
"""

from __future__ import annotations

import enum
import json
import math
from dataclasses import dataclass, field
from typing import Any

__all__ = [
    "MAX_PROBLEMS",
    "CheckResult",
    "Control",
    "EndState",
    "Move",
    "MoveKind",
    "Plane",
    "Problem",
    "Severity",
    "Stock",
    "ToolUse",
    "Units",
]

Point = tuple[float, float, float]

MAX_PROBLEMS = 200
"""Problems a result lists at most; :attr:`CheckResult.more_problems` counts the rest."""


class Control(enum.Enum):
    """Which control's language a program is written in."""

    HAAS = "haas"
    """G-code with Haas / Fanuc macro B (``%``, ``O`` number, ``#`` variables)."""
    HEIDENHAIN = "heidenhain"
    """Heidenhain conversational (Klartext): ``BEGIN PGM ... MM``."""
    ISO = "iso"
    """G-code as a Heidenhain TNC runs it (ISO programs, ``.I`` files)."""

    @property
    def family(self) -> str:
        """The control family a program of this language runs on: ``haas`` or ``heidenhain``."""
        return "haas" if self is Control.HAAS else "heidenhain"


class Severity(enum.Enum):
    """How bad a problem is: an error stops the program on the control (or breaks the part)."""

    ERROR = "error"
    WARNING = "warning"


class Units(enum.Enum):
    """Length units of a program (``G20``/``G21``, ``MM``/``INCH``)."""

    MM = "mm"
    INCH = "inch"


class MoveKind(enum.Enum):
    """How the tool moves between two points."""

    RAPID = "rapid"
    FEED = "feed"
    ARC_CW = "arc_cw"
    ARC_CCW = "arc_ccw"


class Plane(enum.Enum):
    """Plane of an arc: the axes it turns in (``G17`` XY, ``G18`` ZX, ``G19`` YZ)."""

    XY = "xy"
    ZX = "zx"
    YZ = "yz"


@dataclass(frozen=True, slots=True)
class Problem:
    """One finding: the 1-based file ``line``, and for Klartext the ``block`` number too."""

    line: int
    severity: Severity
    message: str
    block: int | None = None

    def format(self, name: str) -> str:
        """``NAME:LINE: error: message`` (with ``(block N)`` for Klartext), as the CLI prints."""
        where = f" (block {self.block})" if self.block is not None else ""
        return f"{name}:{self.line}: {self.severity.value}: {self.message}{where}"


@dataclass(frozen=True, slots=True)
class ToolUse:
    """A tool the program loads: number or name, where first, and what it does there."""

    tool: str
    """``"5"`` for T5 / TOOL CALL 5, or a Heidenhain tool name (``"MILL_D10"``)."""
    line: int
    """File line of the first change to this tool."""
    calls: int = 1
    axis: str | None = None
    """Heidenhain tool axis (``Z``)."""
    speed: float | None = None
    """Spindle speed at the first call (S), if given."""
    feed: float | None = None
    delta_length: float | None = None
    delta_radius: float | None = None
    feed_distance: float = 0.0
    """Cutting distance with this tool (program units)."""


@dataclass(frozen=True, slots=True)
class Move:
    """One straight move or arc, in work coordinates of the program's units.

    An arc has its ``center`` (the point in the arc's ``plane``; the third coordinate is the
    start's) and turns from ``start`` to ``end``; a helix changes the third axis on the way.
    An arc whose ``start`` equals its ``end`` is a full circle.
    """

    kind: MoveKind
    start: Point
    end: Point
    line: int
    tool: str | None = None
    center: Point | None = None
    plane: Plane | None = None
    feed: float | None = None
    """Programmed feed (units per minute; ``None`` for rapids)."""


@dataclass(frozen=True, slots=True)
class Stock:
    """The blank as ``BLK FORM 0.1``/``0.2`` defines it: min and max corner, tool axis."""

    minimum: Point
    maximum: Point
    axis: str = "Z"


@dataclass(frozen=True)
class EndState:
    """Where the dry run left the control: position, tool and variables."""

    position: dict[str, float] = field(default_factory=dict)
    """Work coordinates of the axes whose position is known."""
    machine_position: dict[str, float] = field(default_factory=dict)
    """Machine coordinates of the axes whose position and work offset are known."""
    tool: str | None = None
    variables: dict[int, float] = field(default_factory=dict)
    """Macro variables (G-code: ``#n``) or Q parameters (Klartext: ``Q1`` as 1) set."""
    ended: bool = False
    """True when the program reached its end (M30, M02, M99 or END PGM)."""


@dataclass(frozen=True)
class CheckResult:
    """Everything one dry run found out about a program."""

    control: Control
    name: str = ""
    problems: tuple[Problem, ...] = ()
    tools: tuple[ToolUse, ...] = ()
    extents: dict[str, tuple[float, float]] = field(default_factory=dict)
    """Smallest and largest position per axis (``"X"``, ``"Y"``, ``"Z"``) in work coordinates."""
    rapid_distance: float = 0.0
    feed_distance: float = 0.0
    cycle_time_s: float = 0.0
    """Estimated run time: feeds at their programmed rate, rapids at the machine's (estimate)."""
    moves: tuple[Move, ...] = ()
    stock: Stock | None = None
    units: Units | None = None
    blocks: int = 0
    """Blocks the dry run executed (a loop counts each pass)."""
    end: EndState = field(default_factory=EndState)
    dialect: str | None = None
    """G-code: the control dialect checked against (``haas-lathe``, ``fanuc-mill``; ``mill``
    or ``lathe`` when guessed: Haas and Fanuc codes of that kind); None for Heidenhain."""
    more_problems: int = 0
    """Problems found beyond the :data:`MAX_PROBLEMS` listed (counted, not listed)."""
    more_errors: int = 0
    """How many of :attr:`more_problems` are errors (so :attr:`ok` still sees them)."""
    move_count: int = 0
    """Moves the run made, kept in :attr:`moves` or not (the budget's ``moves``)."""

    @property
    def errors(self) -> tuple[Problem, ...]:
        """The problems of severity error."""
        return tuple(p for p in self.problems if p.severity is Severity.ERROR)

    @property
    def warnings(self) -> tuple[Problem, ...]:
        """The problems of severity warning."""
        return tuple(p for p in self.problems if p.severity is Severity.WARNING)

    @property
    def ok(self) -> bool:
        """True when there is no error (warnings allowed), listed or beyond the cap."""
        return not self.errors and not self.more_errors

    def summary(self) -> str:
        """One line: errors, warnings, tools, moves and the estimated time."""
        # past the cap problems are counted, not listed: the counts include them
        errors = len(self.errors) + self.more_errors
        warnings = len(self.warnings) + self.more_problems - self.more_errors
        unlisted = f" ({self.more_problems} not listed)" if self.more_problems else ""
        moves = max(self.move_count, len(self.moves))
        minutes, seconds = divmod(round(self.cycle_time_s), 60)
        return (
            f"{self.name or 'program'}: {errors} error{'s' * (errors != 1)}, "
            f"{warnings} warning{'s' * (warnings != 1)}{unlisted}; {self._language()}, "
            f"{len(self.tools)} tool{'s' * (len(self.tools) != 1)}, "
            f"{moves} move{'s' * (moves != 1)}, "
            f"about {minutes}:{seconds:02d} min"
        )

    def _language(self) -> str:
        # a guessed mill program keeps its plain name ("haas"); a lathe or a named control
        # says which table it was checked against
        if self.dialect is None or self.dialect == "mill":
            return self.control.value
        return self.dialect

    def to_dict(self) -> dict[str, Any]:
        """The result as plain JSON-ready values (docs/check.md#json)."""
        return {
            "name": self.name,
            "control": self.control.value,
            "dialect": self.dialect,
            "ok": self.ok,
            "units": self.units.value if self.units else None,
            "problems": [
                {
                    "line": p.line,
                    "block": p.block,
                    "severity": p.severity.value,
                    "message": p.message,
                }
                for p in self.problems
            ],
            "more_problems": self.more_problems,
            "tools": [
                {
                    "tool": t.tool,
                    "line": t.line,
                    "calls": t.calls,
                    "axis": t.axis,
                    "speed": t.speed,
                    "feed": t.feed,
                    "delta_length": t.delta_length,
                    "delta_radius": t.delta_radius,
                    "feed_distance": _round(t.feed_distance),
                }
                for t in self.tools
            ],
            "extents": {axis: [_round(lo), _round(hi)] for axis, (lo, hi) in self.extents.items()},
            "rapid_distance": _round(self.rapid_distance),
            "feed_distance": _round(self.feed_distance),
            "cycle_time_s": round(self.cycle_time_s, 1),
            "blocks": self.blocks,
            "move_count": max(self.move_count, len(self.moves)),
            "end": {
                "position": {k: _round(v) for k, v in self.end.position.items()},
                "tool": self.end.tool,
                "ended": self.end.ended,
            },
            "stock": None
            if self.stock is None
            else {
                "min": [_round(v) for v in self.stock.minimum],
                "max": [_round(v) for v in self.stock.maximum],
                "axis": self.stock.axis,
            },
            "moves": [_move_json(m) for m in self.moves],
        }

    def to_json(self) -> str:
        """:meth:`to_dict` as one compact JSON document."""
        return json.dumps(self.to_dict(), separators=(",", ":"), allow_nan=False)


def _round(value: float) -> float:
    # 1e-6 keeps every digit a program writes (4 decimals inch, 3 mm) and drops float noise
    return round(value, 6) if math.isfinite(value) else 0.0


def _move_json(move: Move) -> dict[str, Any]:
    out: dict[str, Any] = {
        "kind": move.kind.value,
        "line": move.line,
        "tool": move.tool,
        "start": [_round(v) for v in move.start],
        "end": [_round(v) for v in move.end],
    }
    if move.center is not None:
        out["center"] = [_round(v) for v in move.center]
        out["plane"] = move.plane.value if move.plane else "xy"
    if move.feed is not None:
        out["feed"] = _round(move.feed)
    return out
