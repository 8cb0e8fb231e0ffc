"""The toolpath a dry run builds: moves, distances, extents, time, tools, travel checks.

Both dry runs (G-code and Klartext) feed one :class:`Toolpath` with straight moves and
arcs in work coordinates; it keeps what the preview and the summary need and checks each
end point (and each arc's extreme points) against the machine's travel when the work offset
in force is known (docs/check.md#machine-limits).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from opendnc.nccheck.result import (
    CheckResult,
    Control,
    EndState,
    Move,
    MoveKind,
    Plane,
    Point,
    Problem,
    Severity,
    Stock,
    ToolUse,
    Units,
)

# Assumptions of the time estimate (docs/check.md#cycle-time): no acceleration, a fixed
# rapid rate unless the machine gives one, a fixed tool change time.
RAPID_MM_PER_MIN = 25_400.0
RAPID_INCH_PER_MIN = 1_000.0
TOOL_CHANGE_S = 4.0
AXIS_NAMES = ("X", "Y", "Z")
_PLANE_AXES = {Plane.XY: (0, 1, 2), Plane.ZX: (2, 0, 1), Plane.YZ: (1, 2, 0)}


def rapid_rate(units: Units) -> float:
    """The assumed rapid traverse in ``units`` per minute (docs/check.md#cycle-time)."""
    return RAPID_INCH_PER_MIN if units is Units.INCH else RAPID_MM_PER_MIN


def radius_arc_center(
    start: tuple[float, float],
    end: tuple[float, float],
    chord: float,
    radius: float,
    *,
    ccw: bool,
) -> tuple[float, float]:
    """The centre (in the plane's two axes) of the arc of ``radius`` from ``start`` to ``end``,
    ``chord`` apart (not 0): of the two circles through both points, the one on the side the
    direction gives; a negative radius (the longer arc) takes the other one. A chord a little
    longer than the diameter (within the caller's tolerance) gives the centre on the chord."""
    (sa, sb), (ea, eb) = start, end
    half = math.sqrt(max(radius * radius - chord * chord / 4, 0.0))
    ua, ub = (ea - sa) / chord, (eb - sb) / chord
    side = 1.0 if ccw ^ (radius < 0) else -1.0
    return (sa + ea) / 2 - side * half * ub, (sb + eb) / 2 + side * half * ua


def short_radius(radius: float, chord: float, tol: float) -> str | None:
    """Why no arc of ``radius`` spans ``chord`` (shorter than half of it, beyond ``tol``)."""
    if abs(radius) < chord / 2 - tol:
        return f"R{radius:g} is too small for a chord of {chord:.4g} (at least {chord / 2:.4g})"
    return None


@dataclass
class _Tool:
    tool: str
    line: int
    calls: int = 1
    axis: str | None = None
    speed: float | None = None
    feed: float | None = None
    delta_length: float | None = None
    delta_radius: float | None = None
    feed_distance: float = 0.0


@dataclass
class _Overrun:
    line: int
    value: float
    count: int = 1


class Toolpath:
    """Accumulates moves; positions are work coordinates, ``None`` where not known."""

    def __init__(
        self,
        *,
        max_moves: int,
        rapid_rate: float = RAPID_MM_PER_MIN,
        travel: dict[str, tuple[float, float]] | None = None,
    ) -> None:
        self.moves: list[Move] = []
        self.max_moves = max_moves
        self.rapid_rate = rapid_rate
        self.rapid = 0.0
        self.feed = 0.0
        self.seconds = 0.0
        self.low = [math.inf, math.inf, math.inf]
        self.high = [-math.inf, -math.inf, -math.inf]
        self.tool: str | None = None
        self._tools: dict[str, _Tool] = {}
        self._current: _Tool | None = None
        self.travel = [(travel or {}).get(axis, (-math.inf, math.inf)) for axis in AXIS_NAMES]
        self.check_travel = bool(travel)
        self._overruns: dict[tuple[int, bool], _Overrun] = {}
        self.moves_dropped = 0
        self.unplaced = 0  # feed moves from or to a position with an axis not known
        self.unplaced_line = 0  # the first of them
        # the last move, kept or not (a corner trims it); a straight move not kept is held
        # as its parts and made a Move only when asked for (most never are)
        self._last: Move | None = None
        self._last_parts: tuple[MoveKind, Point, Point, int, str | None, float | None] | None
        self._last_parts = None
        # the end point of the last move: the next move's start shares it (one tuple, not
        # two, per point: a million moves keep half the points)
        self._last_end: Point | None = None

    # ------------------------------------------------------------------ tools
    def change_tool(self, tool: str, line: int, **info: float | str | None) -> None:
        """Load ``tool`` (counts a change and its time)."""
        self.tool = tool
        known = self._tools.get(tool)
        if known is None:
            known = _Tool(tool, line)
            for key, value in info.items():
                setattr(known, key, value)
            self._tools[tool] = known
        else:
            known.calls += 1
        self._current = known
        self.seconds += TOOL_CHANGE_S

    def spindle_speed(self, speed: float) -> None:
        """The first S after a tool change is that tool's speed (Haas programs set it after M06)."""
        if self._current is not None and self._current.speed is None and speed:
            self._current.speed = speed

    def feed_rate(self, feed: float) -> None:
        """The first F after a tool change is that tool's feed."""
        if self._current is not None and self._current.feed is None and feed:
            self._current.feed = feed

    def result(
        self,
        control: Control,
        name: str,
        problems: list[Problem],
        *,
        units: Units | None,
        blocks: int,
        end: EndState,
        stock: Stock | None = None,
    ) -> CheckResult:
        """What a dry run that drew this path found: ``problems`` by line (in the order found
        where lines tie), with the path's tools, extents, distances, moves and time."""
        return CheckResult(
            control=control,
            name=name,
            problems=tuple(sorted(problems, key=lambda p: p.line)),
            tools=self.tools(),
            extents=self.extents(),
            rapid_distance=self.rapid,
            feed_distance=self.feed,
            cycle_time_s=self.seconds,
            moves=tuple(self.moves),
            move_count=len(self.moves) + self.moves_dropped,
            stock=stock,
            units=units,
            blocks=blocks,
            end=end,
        )

    def tools(self) -> tuple[ToolUse, ...]:
        """Every tool loaded, in order of first use."""
        return tuple(
            ToolUse(
                tool=t.tool,
                line=t.line,
                calls=t.calls,
                axis=t.axis,
                speed=t.speed,
                feed=t.feed,
                delta_length=t.delta_length,
                delta_radius=t.delta_radius,
                feed_distance=t.feed_distance,
            )
            for t in self._tools.values()
        )

    # ------------------------------------------------------------------ moves
    def _see(self, point: tuple[float | None, ...]) -> None:
        low, high = self.low, self.high
        for axis in range(3):
            value = point[axis]
            if value is not None:
                if value < low[axis]:
                    low[axis] = value
                if value > high[axis]:
                    high[axis] = value

    @property
    def last(self) -> Move | None:
        """The last move, kept for the preview or not."""
        if self._last is None and self._last_parts is not None:
            kind, begin, finish, line, tool, feed = self._last_parts
            self._last = Move(kind, begin, finish, line, tool, feed=feed)
        return self._last

    @last.setter
    def last(self, move: Move | None) -> None:
        self._last = move
        self._last_parts = None

    def _add(self, move: Move) -> None:
        self.last = move
        if len(self.moves) < self.max_moves:
            self.moves.append(move)
        else:
            self.moves_dropped += 1

    def line(
        self,
        start: Sequence[float | None],
        end: Sequence[float | None],
        line: int,
        *,
        rapid: bool,
        feed: float | None = None,
        seconds: float | None = None,
        machine_end: Sequence[float | None] | None = None,
    ) -> None:
        """A straight move; ``seconds`` overrides the time from ``feed`` (units per minute)."""
        # the bulk of every program: _see, _count_feed and _add written out here
        x1, y1, z1 = end
        low, high = self.low, self.high
        if x1 is not None:
            if x1 < low[0]:
                low[0] = x1
            if x1 > high[0]:
                high[0] = x1
        if y1 is not None:
            if y1 < low[1]:
                low[1] = y1
            if y1 > high[1]:
                high[1] = y1
        if z1 is not None:
            if z1 < low[2]:
                low[2] = z1
            if z1 > high[2]:
                high[2] = z1
        if machine_end is not None and self.check_travel:
            self._check(machine_end, line)
        x0, y0, z0 = start
        if x0 is None or y0 is None or z0 is None or x1 is None or y1 is None or z1 is None:
            # a move from or to an unknown position is neither drawn nor measured
            if not rapid:  # feed moves: the cut itself goes unmeasured
                if not self.unplaced:
                    self.unplaced_line = line
                self.unplaced += 1
            return
        length = math.hypot(x1 - x0, y1 - y0, z1 - z0)
        if length == 0.0:
            return
        begin: Point = (x0, y0, z0)
        keep = len(self.moves) < self.max_moves
        last_end = self._last_end
        if keep and last_end is not None and begin == last_end:
            begin = last_end  # kept moves share their points
        finish: Point = (x1, y1, z1)
        self._last_end = finish
        if rapid:
            kind = MoveKind.RAPID
            feed = None
            self.rapid += length
            self.seconds += length / self.rapid_rate * 60.0
        else:
            kind = MoveKind.FEED
            self.feed += length
            current = self._current
            if current is not None:
                current.feed_distance += length
            if seconds is not None:
                self.seconds += seconds
            elif feed:
                self.seconds += length / feed * 60.0
        if keep:
            move = Move(kind, begin, finish, line, self.tool, feed=feed)
            self.moves.append(move)
            self._last = move
            self._last_parts = None
        else:
            self.moves_dropped += 1
            self._last = None
            self._last_parts = (kind, begin, finish, line, self.tool, feed)

    def _count_feed(self, length: float, feed: float | None, seconds: float | None) -> None:
        """A cutting move of ``length``: the path's and the tool's feed distance, and its time
        (``seconds`` where the run knows it, else at ``feed``; no feed, no time)."""
        self.feed += length
        if self._current is not None:
            self._current.feed_distance += length
        if seconds is not None:
            self.seconds += seconds
        elif feed:
            self.seconds += length / feed * 60.0

    def arc(
        self,
        start: Point,
        end: Point,
        center: Point,
        plane: Plane,
        line: int,
        *,
        clockwise: bool,
        feed: float | None,
        seconds: float | None = None,
        machine_shift: tuple[float | None, ...] | None = None,
    ) -> float:
        """An arc (helix when the third axis changes); returns its length."""
        a, b, c = _PLANE_AXES[plane]
        ca, cb = center[a], center[b]
        radius = math.hypot(start[a] - ca, start[b] - cb)
        angle0 = math.atan2(start[b] - cb, start[a] - ca)
        angle1 = math.atan2(end[b] - cb, end[a] - ca)
        sweep = (angle0 - angle1) if clockwise else (angle1 - angle0)
        sweep %= 2 * math.pi
        if sweep < 1e-12:
            sweep = 2 * math.pi  # same start and end: a full circle
        planar = sweep * radius
        length = math.hypot(planar, end[c] - start[c])
        # extremes: the quadrant points the arc passes through
        points: list[tuple[float | None, ...]] = [end]
        for quadrant in range(4):
            theta = quadrant * math.pi / 2
            delta = (angle0 - theta) if clockwise else (theta - angle0)
            if delta % (2 * math.pi) <= sweep:
                q = [0.0, 0.0, 0.0]
                q[a] = ca + radius * math.cos(theta)
                q[b] = cb + radius * math.sin(theta)
                q[c] = start[c]
                points.append(tuple(q))
        for p in points:
            self._see(p)
            if machine_shift is not None and self.check_travel:
                self._check(
                    tuple(
                        None if s is None or v is None else v + s
                        for v, s in zip(p, machine_shift, strict=False)
                    ),
                    line,
                )
        self._count_feed(length, feed, seconds)
        kind = MoveKind.ARC_CW if clockwise else MoveKind.ARC_CCW
        self._add(Move(kind, start, end, line, self.tool, center=center, plane=plane, feed=feed))
        self._last_end = end
        return length

    def trim_last_feed(self, length: float) -> Move | None:
        """Shorten the last move, a straight feed, by ``length`` at its end (for a rounded or
        chamfered corner); the shortened move, or None when that is not possible."""
        last = self.last
        if last is None:
            return None
        if last.kind is not MoveKind.FEED:
            return None
        full = math.dist(last.start, last.end)
        if length >= full - 1e-9:
            return None
        k = (full - length) / full
        end = tuple(s + (e - s) * k for s, e in zip(last.start, last.end, strict=True))
        trimmed = Move(
            last.kind, last.start, (end[0], end[1], end[2]), last.line, last.tool, feed=last.feed
        )
        self.last = trimmed
        if self.moves and self.moves[-1] is last:
            self.moves[-1] = trimmed
        self.feed -= length
        if self._current is not None:
            self._current.feed_distance -= length
        if last.feed:
            self.seconds -= length / last.feed * 60.0
        return trimmed

    def scale_travel(self, factor: float) -> None:
        """Express the travel in other units (the program's, when the machine's differ)."""
        self.travel = [(low * factor, high * factor) for low, high in self.travel]

    def dwell(self, seconds: float) -> None:
        """Time spent without moving (G04, dwell of a cycle)."""
        if seconds > 0 and math.isfinite(seconds):
            self.seconds += seconds

    # ------------------------------------------------------------------ travel
    def _check(self, machine: Sequence[float | None], line: int) -> None:
        for axis in range(3):
            value = machine[axis]
            if value is None:
                continue
            low, high = self.travel[axis]
            tolerance = 1e-6
            if value < low - tolerance or value > high + tolerance:
                key = (axis, value > high)
                seen = self._overruns.get(key)
                if seen is None:
                    self._overruns[key] = _Overrun(line, value)
                else:
                    seen.count += 1

    def travel_problems(self, machine_name: str) -> list[Problem]:
        """One error per axis and side the program goes beyond (first move, and how many)."""
        out = []
        for (axis, above), overrun in self._overruns.items():
            low, high = self.travel[axis]
            name = AXIS_NAMES[axis]
            side = (
                f"above the {name} travel's maximum {high:g}"
                if above
                else (f"below the {name} travel's minimum {low:g}")
            )
            more = f" ({overrun.count} points in all)" if overrun.count > 1 else ""
            out.append(
                Problem(
                    overrun.line,
                    Severity.ERROR,
                    f"{name} goes to {overrun.value:g} in machine coordinates, {side} of "
                    f"{machine_name or 'the machine'}{more}",
                )
            )
        return sorted(out, key=lambda p: p.line)

    def extents(self) -> dict[str, tuple[float, float]]:
        """Smallest and largest position per axis seen."""
        return {
            AXIS_NAMES[i]: (self.low[i], self.high[i])
            for i in range(3)
            if self.low[i] <= self.high[i]
        }
