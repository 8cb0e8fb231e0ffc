"""The probing grid: size, pitch, origin, units, and the serpentine visiting order.

Columns run along X, rows along Y. Points are numbered 1..N in the order the program visits
them: row 1 left to right, row 2 right to left, and so on (serpentine), so the machine never
makes a long move back across the part between rows. Coordinates are rounded to the
resolution the program prints them with (1e-4 in, 1e-3 mm), so what the capture compares
is what the control can write.
"""

from __future__ import annotations

import enum
import math
import re
from collections.abc import Iterator
from dataclasses import dataclass
from functools import cached_property

from opendnc.errors import InputError

MAX_POINTS = 99_999
"""Most points one program may probe (the point number prints with at most five places)."""


class Units(enum.Enum):
    """Program units: G20 inch or G21 millimetre."""

    INCH = "inch"
    MM = "mm"

    @property
    def decimals(self) -> int:
        """Places printed after the point: 4 for inch (0.0001 in), 3 for mm (0.001 mm)."""
        return 4 if self is Units.INCH else 3

    @property
    def resolution(self) -> float:
        """Smallest printed step in these units."""
        return 10.0**-self.decimals

    @property
    def g_code(self) -> str:
        """``G20`` or ``G21``."""
        return "G20" if self is Units.INCH else "G21"

    @classmethod
    def parse(cls, text: str) -> Units:
        """``inch``/``in``/``g20`` or ``mm``/``metric``/``g21``."""
        key = text.strip().lower()
        if key in ("inch", "in", "g20"):
            return cls.INCH
        if key in ("mm", "metric", "g21"):
            return cls.MM
        raise InputError(f"bad units {text!r}: use inch or mm")


@dataclass(frozen=True, slots=True)
class GridPoint:
    """One grid point: its number in visiting order, row/column (from 1), and X, Y."""

    number: int
    row: int
    col: int
    x: float
    y: float


_GRID = re.compile(r"\s*(\d+)\s*[xX*×]\s*(\d+)\s*")


def parse_grid(text: str) -> tuple[int, int]:
    """``10x10`` -> (columns along X, rows along Y)."""
    match = _GRID.fullmatch(text)
    if match is None:
        raise InputError(f"bad grid {text!r}: use COLUMNSxROWS, e.g. 10x10")
    return int(match.group(1)), int(match.group(2))


def parse_origin(text: str) -> tuple[float, float]:
    """``X,Y`` (``1.5,-2``) -> floats."""
    parts = text.split(",")
    problem = InputError(f"bad origin {text!r}: use X,Y, e.g. 0,0 or 1.5,-2")
    if len(parts) != 2:
        raise problem
    try:
        x, y = float(parts[0]), float(parts[1])
    except ValueError:
        raise problem from None
    if not (math.isfinite(x) and math.isfinite(y)):
        raise InputError(f"bad origin {text!r}: X and Y must be finite")
    return x, y


@dataclass(frozen=True)
class Grid:
    """A rectangular probing grid, checked on creation."""

    columns: int
    rows: int
    pitch_x: float
    pitch_y: float
    origin_x: float = 0.0
    origin_y: float = 0.0
    units: Units = Units.INCH

    def __post_init__(self) -> None:
        if self.columns < 2 or self.rows < 2:
            raise InputError(
                f"grid {self.columns}x{self.rows} is too small: a surface needs at least 2x2"
            )
        if self.columns * self.rows > MAX_POINTS:
            raise InputError(
                f"grid {self.columns}x{self.rows} has {self.columns * self.rows} points; "
                f"at most {MAX_POINTS} fit one program"
            )
        for name, pitch in (("pitch", self.pitch_x), ("pitch-y", self.pitch_y)):
            if not math.isfinite(pitch) or pitch <= 0:
                raise InputError(f"{name} must be a positive number, got {pitch:g}")
            if round(pitch, self.units.decimals) <= 0:
                raise InputError(
                    f"{name} {pitch:g} is below the printed resolution "
                    f"{self.units.resolution:g} {self.units.value}"
                )
        if not (math.isfinite(self.origin_x) and math.isfinite(self.origin_y)):
            raise InputError("grid origin must be finite")

    @property
    def size(self) -> int:
        """Number of points."""
        return self.columns * self.rows

    @property
    def label(self) -> str:
        """``10x10``."""
        return f"{self.columns}x{self.rows}"

    def coordinate(self, row: int, col: int) -> tuple[float, float]:
        """X, Y of ``row``/``col`` (from 1), rounded to the printed resolution."""
        places = self.units.decimals
        x = round(self.origin_x + (col - 1) * self.pitch_x, places)
        y = round(self.origin_y + (row - 1) * self.pitch_y, places)
        return x + 0.0, y + 0.0  # no negative zero

    @cached_property
    def points(self) -> tuple[GridPoint, ...]:
        """Every point in visiting (serpentine) order; ``points[n - 1].number == n``."""
        return tuple(self._serpentine())

    def _serpentine(self) -> Iterator[GridPoint]:
        number = 0
        for row in range(1, self.rows + 1):
            cols = range(1, self.columns + 1)
            for col in cols if row % 2 else reversed(cols):
                number += 1
                x, y = self.coordinate(row, col)
                yield GridPoint(number, row, col, x, y)

    def point(self, number: int) -> GridPoint:
        """Grid point ``number`` (1..size); :class:`InputError` outside."""
        if not 1 <= number <= self.size:
            raise InputError(f"point {number} is not on the {self.label} grid")
        return self.points[number - 1]
