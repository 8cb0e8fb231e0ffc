"""Synthetic part surfaces for simulated probing (``--surface SPEC``).

A surface maps machine X, Y to the machine Z a probe touches there. Specs:

``flat:z0``
    a level surface at ``z0``.
``plane:a,b,c``
    ``z = a*x + b*y + c``.
``sine:amp,period[,z0]``
    ``z = z0 + amp * sin(2*pi*x/period) * cos(2*pi*y/period)`` (an egg-crate that already
    varies along the X axis, where grid probing usually starts).
``bowl:depth,radius[,cx,cy[,z0]]``
    a paraboloid dish centred on ``cx, cy``: ``z = z0 - depth * (1 - r**2/radius**2)`` inside
    ``radius``, ``z0`` outside.
``wave:amp,period[,z0]``
    ripples along X only: ``z = z0 + amp * sin(2*pi*x/period)``.
``csv:PATH``
    a measured height map: rows of ``x,y,z`` on a regular grid (a header row naming
    ``x,y,z`` and ``#`` comment lines allowed, so an ``opendnc surface capture`` file loads
    as is), interpolated bilinearly; outside the map there is no surface (the probe alarms).
"""

from __future__ import annotations

import bisect
import csv
import math
from dataclasses import dataclass
from pathlib import Path

from opendnc.errors import InputError

KINDS = {"flat": (1, 1), "plane": (3, 3), "sine": (2, 3), "bowl": (2, 5), "wave": (2, 3)}


@dataclass(frozen=True, slots=True)
class SurfaceSpec:
    """A parsed ``--surface`` spec; call it with ``(x, y)`` to get ``z``."""

    kind: str
    params: tuple[float, ...]

    def __call__(self, x: float, y: float) -> float:
        p = self.params
        if self.kind == "flat":
            return p[0]
        if self.kind == "plane":
            return p[0] * x + p[1] * y + p[2]
        if self.kind == "sine":
            z0 = p[2] if len(p) > 2 else 0.0
            return z0 + p[0] * math.sin(2 * math.pi * x / p[1]) * math.cos(2 * math.pi * y / p[1])
        if self.kind == "wave":
            z0 = p[2] if len(p) > 2 else 0.0
            return z0 + p[0] * math.sin(2 * math.pi * x / p[1])
        depth, radius = p[0], p[1]
        cx, cy = (p[2], p[3]) if len(p) >= 4 else (0.0, 0.0)
        z0 = p[4] if len(p) == 5 else 0.0
        r2 = (x - cx) ** 2 + (y - cy) ** 2
        return z0 - depth * (1 - r2 / radius**2) if r2 < radius**2 else z0

    def __str__(self) -> str:
        return f"{self.kind}:" + ",".join(f"{v:g}" for v in self.params)


@dataclass(frozen=True)
class HeightMap:
    """Heights on a regular grid, ``z[j][i]`` at ``xs[i]``, ``ys[j]``; NaN off the map."""

    path: str
    xs: tuple[float, ...]
    ys: tuple[float, ...]
    z: tuple[tuple[float, ...], ...]

    def __call__(self, x: float, y: float) -> float:
        xs, ys = self.xs, self.ys
        if not (xs[0] <= x <= xs[-1] and ys[0] <= y <= ys[-1]):
            return math.nan
        i = min(max(bisect.bisect_right(xs, x) - 1, 0), len(xs) - 2)
        j = min(max(bisect.bisect_right(ys, y) - 1, 0), len(ys) - 2)
        tx = (x - xs[i]) / (xs[i + 1] - xs[i])
        ty = (y - ys[j]) / (ys[j + 1] - ys[j])
        row0 = self.z[j][i] * (1 - tx) + self.z[j][i + 1] * tx
        row1 = self.z[j + 1][i] * (1 - tx) + self.z[j + 1][i + 1] * tx
        return row0 * (1 - ty) + row1 * ty

    def __str__(self) -> str:
        return f"csv:{self.path}"


def load_height_map(path: str) -> HeightMap:
    """Read ``x,y,z`` rows on a regular grid; :class:`InputError` says what does not fit."""
    try:
        text = Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read height map {path}: {exc}") from None
    rows = [r for r in csv.reader(line for line in text.splitlines() if not line.startswith("#"))]
    rows = [r for r in rows if any(cell.strip() for cell in r)]
    columns = (0, 1, 2)
    if rows and {"x", "y", "z"} <= {c.strip().lower() for c in rows[0]}:
        header = [c.strip().lower() for c in rows.pop(0)]
        columns = (header.index("x"), header.index("y"), header.index("z"))
    points: dict[tuple[float, float], float] = {}
    for number, row in enumerate(rows, start=1):
        try:
            x, y, z = (float(row[c]) for c in columns)
        except (ValueError, IndexError):
            raise InputError(f"height map {path} row {number}: need numbers x,y,z") from None
        if not all(math.isfinite(v) for v in (x, y, z)):
            raise InputError(f"height map {path} row {number}: x, y, z must be finite")
        points[(x, y)] = z
    xs = tuple(sorted({x for x, _ in points}))
    ys = tuple(sorted({y for _, y in points}))
    if len(xs) < 2 or len(ys) < 2:
        raise InputError(f"height map {path} needs at least 2 distinct X and 2 distinct Y")
    if len(points) != len(xs) * len(ys):
        raise InputError(
            f"height map {path} is not a full grid: {len(points)} points for "
            f"{len(xs)} X by {len(ys)} Y values"
        )
    heights = tuple(tuple(points[(x, y)] for x in xs) for y in ys)
    return HeightMap(path, xs, ys, heights)


def parse_surface(spec: str) -> SurfaceSpec | HeightMap:
    """Parse a spec such as ``plane:0.01,0,-1``; :class:`InputError` names what is wrong."""
    kind, sep, rest = spec.strip().partition(":")
    kind = kind.lower()
    if kind == "csv" and rest:
        return load_height_map(rest)
    if kind not in KINDS or not sep:
        raise InputError(
            f"bad surface {spec!r}: use one of "
            + ", ".join(f"{k}:..." for k in KINDS)
            + " or csv:PATH"
        )
    try:
        params = tuple(float(v) for v in rest.split(","))
    except ValueError:
        raise InputError(f"bad surface {spec!r}: parameters must be numbers") from None
    low, high = KINDS[kind]
    if not low <= len(params) <= high or any(not math.isfinite(v) for v in params):
        raise InputError(f"bad surface {spec!r}: {kind} takes {low}..{high} finite numbers")
    if kind == "bowl" and len(params) == 3:
        raise InputError(f"bad surface {spec!r}: bowl centre needs both cx and cy")
    if kind in ("sine", "wave", "bowl") and params[1] == 0:
        raise InputError(f"bad surface {spec!r}: period/radius must not be 0")
    return SurfaceSpec(kind, params)
