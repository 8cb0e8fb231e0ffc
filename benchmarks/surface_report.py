"""Benchmark: a surface report for a 100 x 100 grid (10,000 points); target under 3 s.

Builds a points file like `opendnc surface capture` writes (a tilted plane with a bump,
1 um noise, printed to 1e-4 in), then times each stage of `opendnc surface report`: reading
the file, the plane fit and statistics, the heat map PNG, the offline HTML (plotly.js
inlined), the STL, and the whole `write_report` call. Medians over ``--repeat`` runs, in this
process (no interpreter start-up; a first warm-up run loads matplotlib and plotly).

    .venv/bin/python benchmarks/surface_report.py
    .venv/bin/python benchmarks/surface_report.py --grid 200 --repeat 3
"""

from __future__ import annotations

import argparse
import math
import random
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from opendnc.surface.fit import analyse
from opendnc.surface.grid import Grid
from opendnc.surface.points import PointRow, PointsWriter
from opendnc.surface.render import heatmap_png, stl_bytes
from opendnc.surface.report import build, html_page, load, write_report

TARGET = 3.0


def make_points(path: Path, size: int) -> None:
    grid = Grid(size, size, 0.05, 0.05)
    rng = random.Random(14)
    rows = []
    for p in grid.points:
        bump = 0.003 * math.exp(-((p.x - 2.0) ** 2 + (p.y - 3.0) ** 2) / 0.5)
        z = f"{0.0008 * p.x - 0.0005 * p.y + bump + rng.gauss(0, 1 / 25400):.4f}"
        rows.append(PointRow(p.number, p.row, p.col, p.x, p.y, float(z), z, "", ""))
    # one fsync for the whole file (the capture syncs per point; that is its cost, not ours)
    with PointsWriter(path, grid) as writer:
        writer._sync = lambda: None  # type: ignore[method-assign]
        for row in rows:
            writer.write(row)


def timed(func: Callable[[], object], repeat: int) -> float:
    runs = []
    for _ in range(repeat):
        start = time.perf_counter()
        func()
        runs.append(time.perf_counter() - start)
    return statistics.median(runs)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--grid", type=int, default=100, help="points per side")
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        tmp = Path(folder)
        points = tmp / "points.csv"
        make_points(points, args.grid)
        write_report(points, tmp / "warm.html", png=tmp / "warm.png")  # imports, font cache
        data = load(points)
        stats = analyse(data.x, data.y, data.z, data.units)
        report = build(data)
        stages = {
            "read points file": lambda: load(points),
            "plane fit + statistics": lambda: analyse(data.x, data.y, data.z, data.units),
            "heat map PNG": lambda: heatmap_png(
                data.x, data.y, stats.residuals, title="t", unit="inch"
            ),
            "HTML (plotly inlined)": lambda: html_page(report),
            "STL": lambda: stl_bytes(data.x, data.y, data.z),
        }
        n = args.grid * args.grid
        print(f"surface report, {args.grid} x {args.grid} = {n} points, median of {args.repeat}")
        for name, func in stages.items():
            print(f"  {name:<26} {timed(func, args.repeat):7.3f} s")
        whole = timed(
            lambda: write_report(points, tmp / "r.html", png=tmp / "r.png", stl=tmp / "r.stl"),
            args.repeat,
        )
        size = (tmp / "r.html").stat().st_size / 1e6
        command = [sys.executable, "-m", "opendnc.cli.main", "surface", "report", str(points)]
        cold = timed(
            lambda: subprocess.run(
                [*command, "-o", str(tmp / "c.html"), "--png", str(tmp / "c.png")],
                check=True,
                capture_output=True,
            ),
            max(1, args.repeat // 2),
        )
        print(f"  {'whole report (HTML+PNG+STL)':<26} {whole:7.3f} s  target < {TARGET:g} s")
        print(f"  {'`opendnc surface report`':<26} {cold:7.3f} s  (new process: imports included)")
        print(f"  HTML size {size:.1f} MB (plotly.js inlined, works offline)")
        slowest = max(whole, cold)
        print(f"verdict: {'OK' if slowest < TARGET else 'SLOWER THAN TARGET'} ({slowest:.2f} s)")


if __name__ == "__main__":
    main()
