"""Surface statistics: least-squares plane, tilt, flatness, RMS, robust outliers (numpy).

Definitions (docs/surface.md):

* plane ``z = a*x + b*y + c`` fitted by least squares to every point;
* tilt per axis: the plane's slope along X (``a``) and Y (``b``), reported as a rise in the
  file's units per 100 mm (mm files) or per inch (inch files), and as an angle in arc-seconds;
* residual: measured ``z`` minus the plane there;
* flatness: peak-to-valley of the residuals (highest minus lowest), i.e. the distance
  between two planes parallel to the least-squares plane that enclose every point;
* RMS: root mean square of the residuals;
* outliers: points whose residual is further than ``k`` robust standard deviations from the
  residuals' median, the robust deviation being 1.4826 x the median absolute deviation (MAD).
  The residuals for this test come from a robust plane (iteratively reweighted least squares
  with Tukey's biweight), so one bad point cannot drag the plane and hide itself or flag its
  neighbours; flatness without the outliers is reported as well.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from opendnc.errors import InputError
from opendnc.surface.grid import Units

ARCSEC_PER_RADIAN = 180 / math.pi * 3600
MAD_TO_SIGMA = 1.4826
"""Scales a median absolute deviation to the standard deviation of normal data."""

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class Plane:
    """``z = a*x + b*y + c``."""

    a: float
    b: float
    c: float

    def at(self, x: FloatArray, y: FloatArray) -> FloatArray:
        """Plane heights at ``x``, ``y``."""
        return np.asarray(self.a * x + self.b * y + self.c, dtype=np.float64)


@dataclass(frozen=True)
class Tilt:
    """Slope of the plane along one axis."""

    axis: str
    slope: float
    """Rise per unit of run (dimensionless)."""
    per_length: float
    """Rise in the file's units per :attr:`length_label`."""
    length_label: str
    arcsec: float


@dataclass(frozen=True)
class SurfaceStats:
    """Everything the report says about a surface."""

    units: Units
    count: int
    plane: Plane
    tilt_x: Tilt
    tilt_y: Tilt
    flatness: float
    rms: float
    residual_min: float
    residual_max: float
    robust_sigma: float
    outlier_k: float
    flatness_inliers: float
    """Peak-to-valley after plane removal with the outliers left out (same plane)."""
    outliers: tuple[int, ...]
    """Indexes (into the input arrays) of the outlying points."""
    residuals: FloatArray


def fit_plane(
    x: FloatArray, y: FloatArray, z: FloatArray, weights: FloatArray | None = None
) -> Plane:
    """Least-squares plane through the points; :class:`InputError` if they do not span one."""
    if len(x) < 3:
        raise InputError(f"a plane needs at least 3 points, got {len(x)}")
    # centre the coordinates: keeps the normal equations well conditioned far from 0,0
    mx, my = float(np.mean(x)), float(np.mean(y))
    design = np.column_stack([x - mx, y - my, np.ones_like(x)])
    if np.linalg.matrix_rank(design) < 3:
        raise InputError("the points lie on one line: no plane (need a 2-D grid)")
    target = z
    if weights is not None:
        root = np.sqrt(weights)
        design, target = design * root[:, None], z * root
    (a, b, c), *_ = np.linalg.lstsq(design, target, rcond=None)
    return Plane(float(a), float(b), float(c - a * mx - b * my))


BISQUARE = 4.685
"""Tukey biweight tuning constant (95 % efficiency on normal data)."""


def robust_residuals(
    x: FloatArray, y: FloatArray, z: FloatArray, floor: float, rounds: int = 20
) -> tuple[FloatArray, float]:
    """Residuals from a biweight IRLS plane and their robust sigma (1.4826 x MAD)."""
    residuals = z - fit_plane(x, y, z).at(x, y)
    sigma = max(MAD_TO_SIGMA * float(np.median(np.abs(residuals - np.median(residuals)))), floor)
    for _ in range(rounds):
        u = (residuals - np.median(residuals)) / (BISQUARE * sigma)
        weights = np.where(np.abs(u) < 1, (1 - u**2) ** 2, 0.0)
        if np.count_nonzero(weights) < 3:
            break
        try:
            plane = fit_plane(x, y, z, weights)
        except InputError:  # the kept points lie on a line: stay with the last plane
            break
        new = z - plane.at(x, y)
        new_sigma = MAD_TO_SIGMA * float(np.median(np.abs(new - np.median(new))))
        done = np.allclose(new, residuals, rtol=0, atol=floor * 1e-3)
        residuals, sigma = new, max(new_sigma, floor)
        if done:
            break
    return residuals, sigma


def tilt(axis: str, slope: float, units: Units) -> Tilt:
    """Tilt along ``axis`` for a plane slope, in the units the shop reads."""
    if units is Units.MM:
        per_length, label = slope * 100.0, "100 mm"
    else:
        per_length, label = slope, "inch"
    return Tilt(axis, slope, per_length, label, math.atan(slope) * ARCSEC_PER_RADIAN)


def analyse(
    x: FloatArray, y: FloatArray, z: FloatArray, units: Units, *, outlier_k: float = 3.5
) -> SurfaceStats:
    """Fit the plane and compute tilt, flatness, RMS and MAD outliers."""
    x, y, z = (np.asarray(v, dtype=np.float64) for v in (x, y, z))
    if not (len(x) == len(y) == len(z)):
        raise InputError("x, y and z must have the same length")
    if not np.all(np.isfinite(np.concatenate([x, y, z]))):
        raise InputError("x, y and z must be finite")
    if outlier_k <= 0:
        raise InputError("the outlier threshold must be positive")
    plane = fit_plane(x, y, z)
    residuals = z - plane.at(x, y)
    floor = units.resolution / 2  # a perfect surface still has rounding: no outliers from it
    robust, sigma = robust_residuals(x, y, z, floor)
    outliers = np.nonzero(np.abs(robust - np.median(robust)) > outlier_k * sigma)[0]
    inliers = np.ones(len(z), dtype=bool)
    inliers[outliers] = False
    kept = residuals[inliers]
    return SurfaceStats(
        units=units,
        count=len(z),
        plane=plane,
        tilt_x=tilt("X", plane.a, units),
        tilt_y=tilt("Y", plane.b, units),
        flatness=float(np.max(residuals) - np.min(residuals)),
        rms=float(np.sqrt(np.mean(residuals**2))),
        residual_min=float(np.min(residuals)),
        residual_max=float(np.max(residuals)),
        robust_sigma=sigma,
        outlier_k=outlier_k,
        flatness_inliers=float(np.max(kept) - np.min(kept)) if kept.size else 0.0,
        outliers=tuple(int(i) for i in outliers),
        residuals=residuals,
    )
