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
"""

from __future__ import annotations

import math
from dataclasses import dataclass

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


def parse_surface(spec: str) -> SurfaceSpec:
    """Parse a spec such as ``plane:0.01,0,-1``; :class:`InputError` names what is wrong."""
    kind, sep, rest = spec.strip().partition(":")
    kind = kind.lower()
    if kind not in KINDS or not sep:
        raise InputError(
            f"bad surface {spec!r}: use one of " + ", ".join(f"{k}:..." for k in KINDS)
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
