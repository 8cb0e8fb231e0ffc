"""The points file: one CSV row per probed point, written as each point arrives.

Columns: ``point,row,col,x,y,z,time,line``. ``x`` and ``y`` are the grid coordinates in
program units; ``z`` is the height exactly as the control printed it; ``time`` is when the
line arrived (ISO 8601, UTC); ``line`` is the raw DPRNT text. Comment lines starting with
``#`` carry the grid (``# grid 10x10 pitch 0.5,0.5 origin 0,0 units inch``) so a report or a
resumed capture knows what was probed. Every row is flushed to disk before the next line is
read, so a crash loses nothing already printed.
"""

from __future__ import annotations

import csv
import math
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import IO

from opendnc.errors import InputError
from opendnc.surface.grid import Grid, Units

COLUMNS = ("point", "row", "col", "x", "y", "z", "time", "line")


@dataclass(frozen=True, slots=True)
class PointRow:
    """One captured point."""

    point: int
    row: int
    col: int
    x: float
    y: float
    z: float
    z_text: str
    time: str
    line: str


def grid_comment(grid: Grid) -> str:
    """The ``# grid ...`` line describing ``grid``."""
    return (
        f"# grid {grid.label} pitch {grid.pitch_x!r},{grid.pitch_y!r} "
        f"origin {grid.origin_x!r},{grid.origin_y!r} units {grid.units.value}"
    )


_COMMENT = re.compile(
    r"#\s*grid\s+(\d+)x(\d+)\s+pitch\s+(\S+),(\S+)\s+origin\s+(\S+),(\S+)\s+units\s+(\w+)"
)


def parse_grid_comment(text: str) -> Grid | None:
    """The grid named by a ``# grid ...`` line, or ``None`` when the line is another comment."""
    match = _COMMENT.match(text.strip())
    if match is None:
        return None
    try:
        values = [float(v) for v in match.group(3, 4, 5, 6)]
    except ValueError:
        raise InputError(f"bad grid comment {text.strip()!r}") from None
    return Grid(
        int(match.group(1)),
        int(match.group(2)),
        values[0],
        values[1],
        values[2],
        values[3],
        Units.parse(match.group(7)),
    )


@dataclass
class PointsFile:
    """What a points file holds: the grid (if it says) and its rows in file order."""

    grid: Grid | None
    rows: list[PointRow]


def read_points(path: Path) -> PointsFile:
    """Read a points file; :class:`InputError` names the line that is wrong."""
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise InputError(f"cannot read {path}: {exc.strerror or exc}") from None
    except UnicodeDecodeError:
        raise InputError(f"{path} is not a text (UTF-8) points file") from None
    grid: Grid | None = None
    data: list[str] = []
    for line in text.splitlines():
        if line.startswith("#"):
            grid = parse_grid_comment(line) or grid
        elif line.strip():
            data.append(line)
    reader = csv.reader(data)
    header = next(reader, None)
    if header is None:
        return PointsFile(grid, [])
    header = [h.strip().lower() for h in header]
    missing = [c for c in ("x", "y", "z") if c not in header]
    if missing:
        raise InputError(f"{path}: no column {', '.join(missing)} (need at least x,y,z)")
    index = {name: header.index(name) for name in header}
    rows: list[PointRow] = []
    for number, record in enumerate(reader, start=2):
        rows.append(_row(path, number, record, index, len(rows) + 1))
    return PointsFile(grid, rows)


def _row(path: Path, number: int, record: list[str], index: dict[str, int], seq: int) -> PointRow:
    def field(name: str, default: str = "") -> str:
        at = index.get(name)
        return record[at].strip() if at is not None and at < len(record) else default

    try:
        x, y, z = float(field("x")), float(field("y")), float(field("z"))
        point = int(field("point", str(seq)))
        row, col = int(field("row", "0")), int(field("col", "0"))
    except ValueError:
        raise InputError(f"{path} row {number}: x, y, z must be numbers: {record!r}") from None
    if not all(math.isfinite(v) for v in (x, y, z)):
        raise InputError(f"{path} row {number}: x, y, z must be finite")
    return PointRow(point, row, col, x, y, z, field("z"), field("time"), field("line"))


class PointsWriter:
    """Append rows to a points file, flushing and syncing each one."""

    def __init__(self, path: Path, grid: Grid, *, resume: bool = False) -> None:
        path = Path(path)
        exists = path.exists() and path.stat().st_size > 0
        if exists and not resume:
            raise InputError(f"{path} exists: use --resume to continue it, or another -o file")
        self.path = path
        self._places = grid.units.decimals
        try:
            self._file: IO[str] = path.open("a", encoding="utf-8", newline="")
        except OSError as exc:
            raise InputError(f"cannot write {path}: {exc.strerror or exc}") from None
        self._csv = csv.writer(self._file, lineterminator="\n")
        if not exists:
            self._file.write(grid_comment(grid) + "\n")
            self._csv.writerow(COLUMNS)
            self._sync()

    def write(self, row: PointRow) -> None:
        """Append ``row`` and make it durable before returning."""
        self._csv.writerow(
            [
                row.point,
                row.row,
                row.col,
                f"{row.x:g}",
                f"{row.y:g}",
                row.z_text,
                row.time,
                row.line,
            ]
        )
        self._sync()

    def _sync(self) -> None:
        self._file.flush()
        os.fsync(self._file.fileno())

    def close(self) -> None:
        """Close the file."""
        self._file.close()

    def __enter__(self) -> PointsWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
