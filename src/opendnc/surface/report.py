"""Build a surface report from a points file: numbers, heat map PNG, offline HTML, STL.

The HTML is one self-contained file: the plotly.js library, the styles and the PNG (as a
data URI) are inside it, so it opens on a shop PC with no internet connection.
"""

from __future__ import annotations

import base64
import html
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from opendnc import __version__
from opendnc.errors import InputError
from opendnc.surface.fit import FloatArray, SurfaceStats, analyse
from opendnc.surface.grid import Grid, Units
from opendnc.surface.points import PointRow, PointsFile, read_points
from opendnc.surface.render import figure_3d, heatmap_png, stl_bytes, write_file

MAX_LISTED = 50
"""Outliers listed in the HTML table (largest deviation first)."""


@dataclass
class SurfaceData:
    """Points ready for the maths: coordinates, heights, point numbers, and what is missing."""

    source: str
    units: Units
    grid: Grid | None
    numbers: list[int]
    x: FloatArray
    y: FloatArray
    z: FloatArray
    missing: list[int]


def load(path: Path, units: Units | None = None) -> SurfaceData:
    """Read a points file; units come from its grid comment, else ``units``, else inch."""
    points: PointsFile = read_points(path)
    if not points.rows:
        raise InputError(f"{path} holds no points")
    chosen = units or (points.grid.units if points.grid else Units.INCH)
    seen: dict[int, int] = {}
    rows: list[PointRow] = []
    for row in points.rows:  # a repeated point keeps its first reading, as the capture does
        if row.point in seen:
            continue
        seen[row.point] = len(rows)
        rows.append(row)
    missing: list[int] = []
    if points.grid is not None:
        missing = [n for n in range(1, points.grid.size + 1) if n not in seen]
    return SurfaceData(
        source=str(path),
        units=chosen,
        grid=points.grid,
        numbers=[r.point for r in rows],
        x=np.array([r.x for r in rows], dtype=np.float64),
        y=np.array([r.y for r in rows], dtype=np.float64),
        z=np.array([r.z for r in rows], dtype=np.float64),
        missing=missing,
    )


@dataclass
class Report:
    """A computed report and its rendered parts."""

    data: SurfaceData
    stats: SurfaceStats
    png: bytes

    def outliers(self) -> list[dict[str, float]]:
        """Each outlier: point number, x, y, z and deviation from the plane."""
        s, d = self.stats, self.data
        return [
            {
                "point": d.numbers[i],
                "x": float(d.x[i]),
                "y": float(d.y[i]),
                "z": float(d.z[i]),
                "deviation": float(s.residuals[i]),
            }
            for i in s.outliers
        ]

    def summary(self) -> dict[str, object]:
        """The numbers, JSON-friendly."""
        s, d = self.stats, self.data
        return {
            "source": d.source,
            "units": d.units.value,
            "points": s.count,
            "missing": d.missing,
            "plane": {"a": s.plane.a, "b": s.plane.b, "c": s.plane.c},
            "tilt": {
                t.axis.lower(): {
                    "slope": t.slope,
                    "per": t.length_label,
                    "rise": t.per_length,
                    "arcsec": t.arcsec,
                }
                for t in (s.tilt_x, s.tilt_y)
            },
            "flatness": s.flatness,
            "flatness_without_outliers": s.flatness_inliers,
            "rms": s.rms,
            "robust_sigma": s.robust_sigma,
            "outliers": self.outliers(),
        }


def build(data: SurfaceData, *, outlier_k: float = 3.5) -> Report:
    """Analyse ``data`` and draw the heat map."""
    stats = analyse(data.x, data.y, data.z, data.units, outlier_k=outlier_k)
    missing_xy = [(p.x, p.y) for p in map(data.grid.point, data.missing)] if data.grid else []
    png = heatmap_png(
        data.x,
        data.y,
        stats.residuals,
        title=f"Deviation from the best-fit plane, flatness {_len(stats.flatness, data.units)}",
        unit=data.units.value,
        outliers=stats.outliers,
        missing_xy=missing_xy,
        decimals=data.units.decimals,
    )
    return Report(data, stats, png)


def _len(value: float, units: Units) -> str:
    places = units.decimals + 1
    return f"{value:.{places}f} {units.value}"


def html_page(report: Report) -> str:
    """The whole offline HTML document."""
    import plotly.io as pio

    d, s = report.data, report.stats
    fig = figure_3d(d.x, d.y, d.z, s.residuals, d.units.value)
    view = pio.to_html(
        fig,
        include_plotlyjs=True,
        full_html=False,
        config={"displaylogo": False, "responsive": True},
        div_id="surface3d",
    )
    u = d.units
    rows = [
        ("Points", f"{s.count}" + (f" of {d.grid.size} ({d.grid.label} grid)" if d.grid else "")),
        ("Missing points", ", ".join(map(str, d.missing)) or "none"),
        ("Flatness (peak to valley after plane removal)", _len(s.flatness, u)),
        ("Flatness without the outliers", _len(s.flatness_inliers, u)),
        ("RMS deviation", _len(s.rms, u)),
        ("Deviation range", f"{_len(s.residual_min, u)} to {_len(s.residual_max, u)}"),
        *(
            (
                f"Tilt along {t.axis}",
                f"{t.per_length:+.{u.decimals + 1}f} {u.value} per {t.length_label} "
                f"({t.arcsec:+.1f} arc-seconds)",
            )
            for t in (s.tilt_x, s.tilt_y)
        ),
        ("Best-fit plane", f"z = {s.plane.a:+.6g}·x {s.plane.b:+.6g}·y {s.plane.c:+.6g}"),
        (
            "Outliers",
            f"{len(s.outliers)} beyond {s.outlier_k:g} robust σ "
            f"(σ = 1.4826 × MAD = {_len(s.robust_sigma, u)})",
        ),
    ]
    table = "\n".join(
        f"<tr><th>{html.escape(k)}</th><td>{html.escape(v)}</td></tr>" for k, v in rows
    )
    listed = sorted(report.outliers(), key=lambda o: -abs(o["deviation"]))
    outlier_rows = "\n".join(
        f"<tr><td>{o['point']:.0f}</td><td>{o['x']:.4f}</td><td>{o['y']:.4f}</td>"
        f"<td>{o['z']:.4f}</td><td>{o['deviation']:+.5f}</td></tr>"
        for o in listed[:MAX_LISTED]
    )
    if len(listed) > MAX_LISTED:
        outlier_rows += (
            f"<tr><td colspan='5'>... and {len(listed) - MAX_LISTED} more "
            "(all in the JSON summary: opendnc surface report --json)</td></tr>"
        )
    outliers = (
        "<h2>Outliers</h2><table class='list'><tr><th>Point</th><th>X</th><th>Y</th>"
        f"<th>Z</th><th>Deviation</th></tr>{outlier_rows}</table>"
        if outlier_rows
        else ""
    )
    png = base64.b64encode(report.png).decode("ascii")
    title = f"Surface report: {Path(d.source).name}"
    made = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>{html.escape(title)}</title>
<style>
body {{ font-family: system-ui, sans-serif; margin: 1.5em auto; max-width: 1000px; color: #222; }}
h1 {{ font-size: 1.4em; }} h2 {{ font-size: 1.15em; margin-top: 1.6em; }}
table {{ border-collapse: collapse; margin: .5em 0; }}
th, td {{ text-align: left; padding: .25em .8em; border-bottom: 1px solid #ddd; }}
th {{ font-weight: 600; }} img {{ max-width: 100%; }}
.note {{ color: #666; font-size: .85em; }}
</style></head>
<body>
<h1>{html.escape(title)}</h1>
<p class="note">Made {made} by opendnc {__version__}. Units: {u.value}.</p>
<h2>Summary</h2>
<table>{table}</table>
{outliers}
<h2>Heat map</h2>
<img alt="deviation from the best-fit plane, with contours" src="data:image/png;base64,{png}">
<h2>3D view</h2>
{view}
<p class="note">Flatness is the distance between two planes parallel to the least-squares
plane that enclose every point. Tilt is the slope of that plane. Everything in this page
works without a network connection.</p>
</body></html>
"""


def write_report(
    points: Path,
    output: Path | None,
    *,
    png: Path | None = None,
    stl: Path | None = None,
    units: Units | None = None,
    outlier_k: float = 3.5,
) -> Report:
    """Load ``points``, compute, and write the requested files (each written whole)."""
    report = build(load(points, units), outlier_k=outlier_k)
    if output is not None:
        write_file(output, html_page(report).encode("utf-8"))
    if png is not None:
        write_file(png, report.png)
    if stl is not None:
        d = report.data
        write_file(stl, stl_bytes(d.x, d.y, d.z, f"opendnc surface {Path(d.source).name}"))
    return report
