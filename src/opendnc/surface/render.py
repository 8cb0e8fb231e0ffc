"""Pictures of a surface: heat map PNG (matplotlib), 3D view (plotly), STL mesh.

Points sitting on a regular grid (what ``opendnc surface program`` probes) are laid out as
a 2-D array with gaps for missing points; anything else is triangulated.
"""

from __future__ import annotations

import io
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from opendnc.atomicfile import atomic_write
from opendnc.errors import InputError
from opendnc.surface.fit import FloatArray


@dataclass(frozen=True)
class GridLayout:
    """Points placed on a regular lattice: ``values[j, i]`` at ``xs[i]``, ``ys[j]`` (NaN gaps)."""

    xs: FloatArray
    ys: FloatArray
    index: npt_Int
    """``index[j, i]``: row of the input arrays there, or -1."""

    def take(self, values: FloatArray) -> FloatArray:
        """``values`` (per input point) arranged on the lattice, NaN where no point."""
        out = np.full(self.index.shape, np.nan)
        mask = self.index >= 0
        out[mask] = values[self.index[mask]]
        return out


npt_Int = np.ndarray  # an integer array; numpy's typing has no shorter spelling


def layout(x: FloatArray, y: FloatArray, decimals: int = 6) -> GridLayout | None:
    """A lattice holding every point once, or ``None`` when the points are scattered."""
    rx, ry = np.round(x, decimals), np.round(y, decimals)
    xs, xi = np.unique(rx, return_inverse=True)
    ys, yi = np.unique(ry, return_inverse=True)
    if len(xs) * len(ys) > 2 * len(x) + 4:
        return None
    index = np.full((len(ys), len(xs)), -1, dtype=np.int64)
    if np.any(index[yi, xi] != -1):
        return None
    index[yi, xi] = np.arange(len(x))
    if len(np.unique(index[yi, xi])) != len(x):  # two points on one lattice node
        return None
    return GridLayout(xs, ys, index)


def heatmap_png(
    x: FloatArray,
    y: FloatArray,
    values: FloatArray,
    *,
    title: str,
    unit: str,
    outliers: tuple[int, ...] = (),
    missing_xy: list[tuple[float, float]] | None = None,
    decimals: int = 4,
) -> bytes:
    """A heat map of ``values`` with contour lines, outliers ringed, missing points crossed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.cm import ScalarMappable
    from matplotlib.contour import ContourSet
    from matplotlib.tri import Triangulation

    fig, ax = plt.subplots(figsize=(8, 6.2), dpi=110)
    mesh: ScalarMappable
    lines: ContourSet
    try:
        # the full range: a real feature (a bump) may be flagged as outlying points, and the
        # picture must still show it; eight contour levels keep the labels readable
        low, high = float(np.min(values)), float(np.max(values))
        if high <= low:
            low, high = low - 1e-9, high + 1e-9
        levels = np.linspace(low, high, 10)[1:-1]
        contour_ok = float(np.ptp(values)) > 0
        label = f"%.{decimals + 1}f"
        grid = layout(x, y)
        if grid is not None and len(grid.xs) > 1 and len(grid.ys) > 1:
            z = np.ma.masked_invalid(grid.take(values))
            mesh = ax.pcolormesh(
                grid.xs, grid.ys, z, shading="nearest", cmap="RdYlBu_r", vmin=low, vmax=high
            )
            if contour_ok and z.count() >= 4:
                lines = ax.contour(grid.xs, grid.ys, z, levels=levels, colors="k", linewidths=0.6)
                ax.clabel(lines, fontsize=7, fmt=label)
        else:
            tri = Triangulation(x, y)
            mesh = ax.tripcolor(
                tri, values, shading="gouraud", cmap="RdYlBu_r", vmin=low, vmax=high
            )
            if contour_ok:
                lines = ax.tricontour(tri, values, levels=levels, colors="k", linewidths=0.6)
                ax.clabel(lines, fontsize=7, fmt=label)
        # markers shrink with the grid so a dense grid stays readable (axes ~ 450 pt wide)
        across = max(len(np.unique(np.round(x, 6))), len(np.unique(np.round(y, 6))), 1)
        ring = float(np.clip((0.8 * 450 / across) ** 2, 6, 90))
        stroke = 1.6 if across <= 30 else 0.6
        if len(x) <= 2500:
            ax.scatter(x, y, s=4, c="k", alpha=0.35, linewidths=0)
        if outliers:
            idx = list(outliers)
            ax.scatter(
                x[idx],
                y[idx],
                s=ring,
                facecolors="none",
                edgecolors="magenta",
                linewidths=stroke,
                alpha=1.0 if across <= 30 else 0.7,
                label="outlier",
            )
        if missing_xy:
            mx, my = zip(*missing_xy, strict=True)
            ax.scatter(mx, my, marker="x", s=ring * 0.7, c="k", linewidths=1.6, label="missing")
        if outliers or missing_xy:
            ax.legend(loc="upper right", fontsize=8, framealpha=0.8)
        bar = fig.colorbar(mesh, ax=ax)
        bar.set_label(f"deviation from the plane ({unit})")
        ax.set_title(title)
        ax.set_xlabel(f"X ({unit})")
        ax.set_ylabel(f"Y ({unit})")
        ax.set_aspect("equal", adjustable="box")
        fig.tight_layout()
        buffer = io.BytesIO()
        fig.savefig(buffer, format="png")
        return buffer.getvalue()
    finally:
        plt.close(fig)


def figure_3d(
    x: FloatArray, y: FloatArray, z: FloatArray, residuals: FloatArray, unit: str
) -> object:
    """A plotly figure: measured surface coloured by deviation from the best-fit plane."""
    import plotly.graph_objects as go

    grid = layout(x, y)
    hover = f"X %{{x:.4f}} {unit}<br>Y %{{y:.4f}} {unit}<br>Z %{{z:.4f}} {unit}"
    if grid is not None and len(grid.xs) > 1 and len(grid.ys) > 1:
        trace = go.Surface(
            x=grid.xs,
            y=grid.ys,
            z=grid.take(z),
            surfacecolor=grid.take(residuals),
            colorscale="RdYlBu_r",
            colorbar={"title": {"text": f"deviation ({unit})"}},
            hovertemplate=hover + "<extra></extra>",
        )
    else:
        trace = go.Mesh3d(
            x=x,
            y=y,
            z=z,
            intensity=residuals,
            colorscale="RdYlBu_r",
            delaunayaxis="z",
            colorbar={"title": {"text": f"deviation ({unit})"}},
            hovertemplate=hover + "<extra></extra>",
        )
    fig = go.Figure(trace)
    fig.add_trace(
        go.Scatter3d(
            x=x,
            y=y,
            z=z,
            mode="markers",
            marker={"size": 2, "color": "black"},
            name="points",
            hovertemplate=hover + "<extra></extra>",
        )
    )
    fig.update_layout(
        scene={
            "xaxis_title": f"X ({unit})",
            "yaxis_title": f"Y ({unit})",
            "zaxis_title": f"Z ({unit})",
            "aspectmode": "manual",
            "aspectratio": {
                "x": 1,
                "y": float(np.ptp(y) / np.ptp(x)) if np.ptp(x) else 1,
                "z": 0.4,
            },
        },
        margin={"l": 0, "r": 0, "t": 30, "b": 0},
        height=560,
        showlegend=False,
        title={"text": "3D view (Z exaggerated to fit; drag to turn)"},
    )
    return fig


def stl_bytes(x: FloatArray, y: FloatArray, z: FloatArray, name: str = "opendnc surface") -> bytes:
    """A binary STL of the measured surface (one open sheet, two triangles per grid cell)."""
    grid = layout(x, y)
    triangles: list[tuple[int, int, int]] = []
    if grid is not None:
        idx = grid.index
        for j in range(idx.shape[0] - 1):
            for i in range(idx.shape[1] - 1):
                a, b, c, d = idx[j, i], idx[j, i + 1], idx[j + 1, i + 1], idx[j + 1, i]
                if min(a, b, c) >= 0:
                    triangles.append((a, b, c))
                if min(a, c, d) >= 0:
                    triangles.append((a, c, d))
    else:
        from matplotlib.tri import Triangulation

        triangles = [(int(a), int(b), int(c)) for a, b, c in Triangulation(x, y).triangles]
    vertices = np.column_stack([x, y, z]).astype(np.float64)
    tri = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    p0, p1, p2 = vertices[tri[:, 0]], vertices[tri[:, 1]], vertices[tri[:, 2]]
    normals = np.cross(p1 - p0, p2 - p0)
    lengths = np.linalg.norm(normals, axis=1, keepdims=True)
    normals = np.divide(normals, lengths, out=np.zeros_like(normals), where=lengths > 0)
    record = np.zeros(
        len(tri),
        dtype=[
            ("n", "<f4", 3),
            ("p0", "<f4", 3),
            ("p1", "<f4", 3),
            ("p2", "<f4", 3),
            ("attr", "<u2"),
        ],
    )
    record["n"], record["p0"], record["p1"], record["p2"] = normals, p0, p1, p2
    header = name.encode("ascii", "replace")[:80].ljust(80, b" ")
    return header + struct.pack("<I", len(tri)) + record.tobytes()


def write_file(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` whole or not at all."""
    try:
        with atomic_write(path) as out:
            out.write(data)
    except OSError as exc:
        raise InputError(f"cannot write {path}: {exc.strerror or exc}") from None
