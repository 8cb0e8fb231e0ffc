"""The toolpath of a dry run as few polylines, and their compact binary form for the preview.

A checked program can hold a million moves; a preview needs its shape, not every block. The
:func:`build` pass turns the :class:`~opendnc.nccheck.result.Move` list into *runs*: polylines
of one kind (rapid or cutting) and one tool, arcs cut into chords, straight stretches merged.
Every point it drops lies within the tolerance of the polyline it keeps (about a pixel of
the whole part on a screen, see :func:`default_tolerance`), and when the result is still
larger than the point budget the tolerance doubles until it fits: the shape stays, the size
is bounded.

:func:`encode` writes a backplot as little-endian binary (docs/check.md#toolpath-binary)::

    offset  type                 what
    0       4 bytes              b"ODTP"
    4       u32                  format version (1)
    8       u32                  M: bytes of the metadata JSON (a multiple of 4)
    12      u32                  R: runs
    16      u32                  P: points
    20      M bytes              metadata, UTF-8 JSON padded with spaces
    20+M    R x 4 u32            runs: first point, point count, flags (bit 0: rapid), tool index
                                 (0xFFFFFFFF: no tool)
    ...     P x 3 f32            points x, y, z (work coordinates, program units)
    ...     P u32                the file line of each point's move

so a browser reads it with typed-array views and no parsing; :func:`decode` reads it back.
"""

from __future__ import annotations

import json
import math
import struct
import sys
from array import array
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from opendnc.errors import InputError
from opendnc.nccheck.result import Move, MoveKind, Plane

__all__ = [
    "FORMAT_VERSION",
    "MAGIC",
    "MAX_POINTS",
    "NO_TOOL",
    "Backplot",
    "Run",
    "build",
    "decode",
    "default_tolerance",
    "encode",
]

MAGIC = b"ODTP"
FORMAT_VERSION = 1
NO_TOOL = 0xFFFFFFFF
MAX_POINTS = 150_000
"""Default point budget: 1.8 MB of coordinates at most, drawn in milliseconds by WebGL."""
TOLERANCE_PARTS = 4000
"""The default tolerance is the part's diagonal over this: a quarter pixel of a 1000-pixel
view of the whole part (zoomed four times, still a pixel)."""
MAX_CHORDS = 1024  # per arc: a huge arc with a tiny tolerance stays bounded
RAPID = 1  # flag bit of a run
_HEADER = struct.Struct("<4sIIII")
_PLANE_AXES = {Plane.XY: (0, 1, 2), Plane.ZX: (2, 0, 1), Plane.YZ: (1, 2, 0)}
_LITTLE = sys.byteorder == "little"

Point = tuple[float, float, float]


@dataclass(frozen=True, slots=True)
class Run:
    """A polyline of one kind and tool: ``count`` points from point index ``first``."""

    first: int
    count: int
    rapid: bool
    tool: int
    """Index into :attr:`Backplot.tools`, or -1 when no tool is loaded."""


@dataclass(frozen=True)
class Backplot:
    """Decimated polylines of a toolpath, ready to draw."""

    runs: tuple[Run, ...]
    points: array[float]
    """x, y, z of every point, flat (``array('f')``)."""
    lines: array[int]
    """File line of each point (``array('I')``)."""
    tools: tuple[str, ...] = ()
    moves: int = 0
    """Moves of the dry run this was built from."""
    tolerance: float = 0.0
    """How far a dropped point may lie from the drawn polyline (program units)."""
    meta: dict[str, Any] = field(default_factory=dict)
    """Extra facts carried in the binary's metadata (units, stock, bounds)."""

    @property
    def point_count(self) -> int:
        """Points over all runs."""
        return len(self.lines)

    def run_points(self, run: Run) -> list[Point]:
        """The points of ``run``."""
        p = self.points
        return [
            (p[3 * i], p[3 * i + 1], p[3 * i + 2]) for i in range(run.first, run.first + run.count)
        ]


def default_tolerance(
    moves: Sequence[Move], extents: dict[str, tuple[float, float]] | None = None
) -> float:
    """The part's diagonal over :data:`TOLERANCE_PARTS`: from ``extents`` (the dry run's, per
    axis) when given, else from the moves' end points and arcs' circles; a thousandth of a
    unit for a path with no extent."""
    if extents:
        diagonal = math.sqrt(sum((hi - lo) ** 2 for lo, hi in extents.values() if hi >= lo))
        if math.isfinite(diagonal) and diagonal > 0.0:
            return diagonal / TOLERANCE_PARTS
    low = [math.inf] * 3
    high = [-math.inf] * 3
    for move in moves:
        for point in (move.start, move.end):
            for axis in range(3):
                value = point[axis]
                if value < low[axis]:
                    low[axis] = value
                if value > high[axis]:
                    high[axis] = value
        if move.center is not None:
            a, b, _ = _PLANE_AXES[move.plane or Plane.XY]
            radius = math.hypot(move.start[a] - move.center[a], move.start[b] - move.center[b])
            for axis in (a, b):
                low[axis] = min(low[axis], move.center[axis] - radius)
                high[axis] = max(high[axis], move.center[axis] + radius)
    spans = [hi - lo for lo, hi in zip(low, high, strict=True) if hi >= lo]
    diagonal = math.sqrt(sum(s * s for s in spans)) if spans else 0.0
    if not math.isfinite(diagonal) or diagonal <= 0.0:
        return 1e-3
    return diagonal / TOLERANCE_PARTS


def build(
    moves: Sequence[Move],
    *,
    tools: Sequence[str] = (),
    max_points: int = MAX_POINTS,
    tolerance: float | None = None,
    extents: dict[str, tuple[float, float]] | None = None,
    meta: dict[str, Any] | None = None,
) -> Backplot:
    """Decimate ``moves`` into runs within ``tolerance`` (default :func:`default_tolerance`
    of the moves, or of ``extents`` when given),
    doubling it until at most ``max_points`` remain (a run keeps at least its two ends, so a
    path of very many separate runs may stay above the budget). ``tools`` orders the tool
    index (tools first seen in the moves are added after them)."""
    if tolerance is not None and tolerance > 0 and math.isfinite(tolerance):
        tol = tolerance
    else:
        tol = default_tolerance(moves, extents)
    names = list(dict.fromkeys(tools))
    for move in moves:  # every tool a move names has an index, listed or not
        if move.tool is not None and move.tool not in names:
            names.append(move.tool)
    index = {name: i for i, name in enumerate(names)}
    while True:
        runs, points, lines = _decimate(moves, index, tol)
        if len(lines) <= max_points or tol > 1e12:
            break
        tol *= 2.0
    return Backplot(
        runs=tuple(runs),
        points=points,
        lines=lines,
        tools=tuple(names),
        moves=len(moves),
        tolerance=tol,
        meta=dict(meta or {}),
    )


class _Simplifier:
    """Reumann-Witkam decimation of one run, point by point: a point is dropped while the
    path stays within ``tol`` of the line from the last kept point along its first direction
    and keeps going forward along it (a reversal is a corner, and kept)."""

    __slots__ = ("anchor", "d", "lines", "pending", "pending_line", "points", "tol")

    def __init__(self, points: array[float], lines: array[int], tol: float) -> None:
        self.points = points
        self.lines = lines
        self.tol = tol
        self.anchor: Point = (0.0, 0.0, 0.0)
        self.d: Point | None = None
        self.pending: Point | None = None
        self.pending_line = 0

    def start(self, point: Point, line: int) -> None:
        self.points.extend(point)
        self.lines.append(line)
        self.anchor = point
        self.d = None
        self.pending = None

    def add(self, point: Point, line: int) -> None:
        ax, ay, az = self.anchor
        x, y, z = point
        tol = self.tol
        d = self.d
        pending = self.pending
        if pending is not None:
            if d is None:
                # no direction yet: the path has not left the anchor's neighbourhood
                dx, dy, dz = pending[0] - ax, pending[1] - ay, pending[2] - az
                length = math.sqrt(dx * dx + dy * dy + dz * dz)
                if length > tol:
                    d = self.d = (dx / length, dy / length, dz / length)
            if d is not None:
                vx, vy, vz = x - ax, y - ay, z - az
                along = vx * d[0] + vy * d[1] + vz * d[2]
                px, py, pz = vx - along * d[0], vy - along * d[1], vz - along * d[2]
                ahead = (
                    (x - pending[0]) * d[0] + (y - pending[1]) * d[1] + (z - pending[2]) * d[2]
                ) >= 0.0
                if ahead and px * px + py * py + pz * pz <= tol * tol:
                    self.pending, self.pending_line = point, line
                    return
                # the path leaves the strip: the pending point is a corner
                self.points.extend(pending)
                self.lines.append(self.pending_line)
                self.anchor = pending
                self.d = None
            # else: the pending point lies within the tolerance of the anchor, so dropping
            # it (even at a sharp turn) stays within the tolerance
        self.pending, self.pending_line = point, line

    def finish(self) -> None:
        if self.pending is not None:
            self.points.extend(self.pending)
            self.lines.append(self.pending_line)
            self.pending = None


def _decimate(
    moves: Sequence[Move], index: dict[str, int], tol: float
) -> tuple[list[Run], array[float], array[int]]:
    points: array[float] = array("f")
    lines: array[int] = array("I")
    runs: list[Run] = []
    simplifier = _Simplifier(points, lines, tol)
    key: tuple[bool, int] | None = None
    first = 0
    last: Point | None = None
    joined = tol * 1e-3
    rapid_kind = MoveKind.RAPID
    isfinite = math.isfinite
    for move in moves:
        start, end = move.start, move.end
        # one test for six values: a sum is finite only when every term is (or overflows)
        if not isfinite(start[0] + start[1] + start[2] + end[0] + end[1] + end[2]):
            continue
        rapid = move.kind is rapid_kind
        tool = index[move.tool] if move.tool is not None else -1
        if (
            last is None
            or key != (rapid, tool)
            or abs(start[0] - last[0]) > joined
            or abs(start[1] - last[1]) > joined
            or abs(start[2] - last[2]) > joined
        ):
            if key is not None:
                simplifier.finish()
                runs.append(Run(first, len(lines) - first, key[0], key[1]))
            key, first = (rapid, tool), len(lines)
            simplifier.start(start, move.line)
        if move.center is not None and move.kind in (MoveKind.ARC_CW, MoveKind.ARC_CCW):
            for point in _chords(move, tol / 2):
                simplifier.add(point, move.line)
        else:
            simplifier.add(end, move.line)
        last = end
    if key is not None:
        simplifier.finish()
        runs.append(Run(first, len(lines) - first, key[0], key[1]))
    return runs, points, lines


def _chords(move: Move, sagitta: float) -> list[Point]:
    """The points after the start of an arc (or helix) cut into chords whose sagitta is at
    most ``sagitta``; the last one is the arc's end."""
    assert move.center is not None
    a, b, c = _PLANE_AXES[move.plane or Plane.XY]
    start, end, center = move.start, move.end, move.center
    ca, cb = center[a], center[b]
    radius = math.hypot(start[a] - ca, start[b] - cb)
    if not math.isfinite(radius) or radius == 0.0:
        return [end]
    angle0 = math.atan2(start[b] - cb, start[a] - ca)
    angle1 = math.atan2(end[b] - cb, end[a] - ca)
    clockwise = move.kind is MoveKind.ARC_CW
    sweep = ((angle0 - angle1) if clockwise else (angle1 - angle0)) % (2 * math.pi)
    if sweep < 1e-12:
        sweep = 2 * math.pi  # the checker's rule: same start and end is a full circle
    step = math.pi / 2 if sagitta >= radius else 2 * math.acos(1 - sagitta / radius)
    n = max(1, min(MAX_CHORDS, math.ceil(sweep / step)))
    signed = -sweep if clockwise else sweep
    out: list[Point] = []
    rise = end[c] - start[c]
    for i in range(1, n):
        theta = angle0 + signed * i / n
        q = [0.0, 0.0, 0.0]
        q[a] = ca + radius * math.cos(theta)
        q[b] = cb + radius * math.sin(theta)
        q[c] = start[c] + rise * i / n
        out.append((q[0], q[1], q[2]))
    out.append(end)
    return out


# -- binary form ------------------------------------------------------------------------------


def encode(backplot: Backplot) -> bytes:
    """The backplot as the little-endian binary of the module's docstring."""
    meta = {
        "moves": backplot.moves,
        "tolerance": backplot.tolerance,
        "tools": list(backplot.tools),
        **backplot.meta,
    }
    text = json.dumps(meta, separators=(",", ":"), allow_nan=False).encode()
    text += b" " * (-len(text) % 4)
    runs: array[int] = array("I")
    for run in backplot.runs:
        runs.extend(
            (run.first, run.count, RAPID if run.rapid else 0, NO_TOOL if run.tool < 0 else run.tool)
        )
    points, lines = array("f", backplot.points), array("I", backplot.lines)
    if not _LITTLE:  # pragma: no cover - the wire is little-endian whatever the host
        for part in (runs, points, lines):
            part.byteswap()
    header = _HEADER.pack(MAGIC, FORMAT_VERSION, len(text), len(backplot.runs), len(lines))
    return b"".join((header, text, runs.tobytes(), points.tobytes(), lines.tobytes()))


def decode(data: bytes) -> Backplot:
    """Read :func:`encode`'s binary back; :class:`~opendnc.errors.InputError` when it is not
    one (wrong magic or version, sizes that do not add up, runs outside the points)."""
    if len(data) < _HEADER.size:
        raise InputError(f"a toolpath is at least {_HEADER.size} bytes, got {len(data)}")
    magic, version, meta_len, run_count, point_count = _HEADER.unpack_from(data)
    if magic != MAGIC:
        raise InputError(f"not a toolpath: starts {magic!r}, not {MAGIC!r}")
    if version != FORMAT_VERSION:
        raise InputError(f"toolpath format {version} is not {FORMAT_VERSION}")
    expected = _HEADER.size + meta_len + 16 * run_count + 16 * point_count
    if meta_len % 4 or len(data) != expected:
        raise InputError(f"a toolpath of these counts is {expected} bytes, got {len(data)}")
    offset = _HEADER.size
    try:
        meta = json.loads(data[offset : offset + meta_len])
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"the toolpath's metadata is not JSON: {exc}") from None
    if not isinstance(meta, dict):
        raise InputError("the toolpath's metadata is not a JSON object")
    offset += meta_len
    runs_raw: array[int] = array("I", data[offset : offset + 16 * run_count])
    offset += 16 * run_count
    points: array[float] = array("f", data[offset : offset + 12 * point_count])
    offset += 12 * point_count
    lines: array[int] = array("I", data[offset:])
    if not _LITTLE:  # pragma: no cover
        for part in (runs_raw, points, lines):
            part.byteswap()
    tools = meta.pop("tools", [])
    if not isinstance(tools, list) or not all(isinstance(t, str) for t in tools):
        raise InputError("the toolpath's tools are not a list of names")
    runs = []
    for i in range(run_count):
        first, count, flags, tool = runs_raw[4 * i : 4 * i + 4]
        if first + count > point_count or (tool != NO_TOOL and tool >= len(tools)):
            raise InputError(f"run {i} points outside the toolpath")
        runs.append(Run(first, count, bool(flags & RAPID), -1 if tool == NO_TOOL else tool))
    moves = meta.pop("moves", 0)
    tolerance = meta.pop("tolerance", 0.0)
    if not isinstance(moves, int) or not isinstance(tolerance, int | float):
        raise InputError("the toolpath's move count or tolerance is not a number")
    return Backplot(
        runs=tuple(runs),
        points=points,
        lines=lines,
        tools=tuple(tools),
        moves=moves,
        tolerance=float(tolerance),
        meta=meta,
    )
