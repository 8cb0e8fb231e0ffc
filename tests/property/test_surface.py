"""Property tests: plane fit and flatness against analytic surfaces; generated programs run
in the program runner and visit exactly their grid; the matcher takes any text."""

from __future__ import annotations

import contextlib
import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from opendnc.sim.haas.machine import MachineState
from opendnc.sim.haas.program import program_lines
from opendnc.sim.haas.runner import AlarmRaised, BlockSource, DprntLine, ProgramRunner, RunnerEvent
from opendnc.surface.capture import PointMatcher, Recorded
from opendnc.surface.fit import ARCSEC_PER_RADIAN, analyse
from opendnc.surface.grid import Grid, Units
from opendnc.surface.program import generate

even = st.integers(1, 12).map(lambda n: 2 * n)
slopes = st.floats(-0.05, 0.05, allow_nan=False)
pitches = st.floats(0.01, 5.0, allow_nan=False)
offsets = st.floats(-100.0, 100.0, allow_nan=False)


@given(even, even, pitches, pitches, offsets, offsets, slopes, slopes, offsets, st.floats(0, 0.01))
def test_plane_and_flatness_match_analytic_values(
    nx: int, ny: int, px: float, py: float, ox: float, oy: float,
    a: float, b: float, c: float, h: float,
) -> None:  # fmt: skip
    # z = plane + a checkerboard of +-h: on an even grid the checkerboard is orthogonal to
    # 1, x and y, so the least-squares plane is exactly (a, b, c) and the flatness is 2h
    i, j = np.meshgrid(np.arange(nx), np.arange(ny))
    x, y = (ox + i * px).ravel(), (oy + j * py).ravel()
    checker = np.where((i + j) % 2 == 0, h, -h).ravel()
    z = a * x + b * y + c + checker
    stats = analyse(x, y, z, Units.MM)
    scale = 1e-9 * (1 + abs(c) + 100 * (abs(a) + abs(b)))
    assert math.isclose(stats.plane.a, a, abs_tol=1e-9)
    assert math.isclose(stats.plane.b, b, abs_tol=1e-9)
    assert math.isclose(stats.plane.c, c, abs_tol=1e-6 + scale * 1e3)
    assert math.isclose(stats.flatness, 2 * h, abs_tol=1e-8)
    assert math.isclose(stats.rms, h, abs_tol=1e-8)
    assert math.isclose(stats.tilt_x.per_length, 100 * a, abs_tol=1e-7)
    assert math.isclose(stats.tilt_y.arcsec, math.atan(b) * ARCSEC_PER_RADIAN, abs_tol=1e-3)


@given(st.integers(4, 15), st.integers(4, 15), slopes, slopes, st.data())
def test_one_spike_is_the_only_outlier(
    nx: int, ny: int, a: float, b: float, data: st.DataObject
) -> None:
    rng = np.random.default_rng(data.draw(st.integers(0, 2**32 - 1)))
    i, j = np.meshgrid(np.arange(nx), np.arange(ny))
    x, y = i.ravel() * 1.0, j.ravel() * 1.0
    # bounded noise: its robust sigma (about 0.74 x the bound) puts every honest point well
    # inside 3.5 sigma, so the property holds for every draw, not just most
    z = a * x + b * y + rng.uniform(-0.001, 0.001, x.size)
    spike = data.draw(st.integers(0, x.size - 1))
    z[spike] += data.draw(st.sampled_from([-1, 1])) * 0.05
    stats = analyse(x, y, z, Units.MM)
    assert stats.outliers == (spike,)


grids = st.builds(
    Grid,
    st.integers(2, 7),
    st.integers(2, 7),
    st.floats(0.001, 3.0),
    st.floats(0.001, 3.0),
    st.floats(-20, 20),
    st.floats(-20, 20),
    st.sampled_from(list(Units)),
)


@settings(max_examples=60, deadline=None)
@given(grids, slopes, slopes)
def test_generated_program_visits_exactly_the_grid(grid: Grid, a: float, b: float) -> None:
    touched: list[tuple[float, float]] = []

    def surface(x: float, y: float) -> float:
        touched.append((x, y))
        return a * x + b * y - 3.0

    machine = MachineState()
    machine.variables[5223] = -3.0
    events: list[RunnerEvent] = []
    runner = ProgramRunner(
        BlockSource(program_lines(generate(grid).text)),
        machine,
        clock=lambda: 0.0,
        emit=events.append,
        surface=surface,
        strict_probe=False,  # random slopes may leave the search window; not the point here
    )
    runner.run()
    assert not [e for e in events if isinstance(e, AlarmRaised)]
    assert touched == [(p.x, p.y) for p in grid.points]  # serpentine, each point once
    matcher = PointMatcher(grid)
    lines = [e.text for e in events if isinstance(e, DprntLine)]
    recorded = [ev for text in lines for ev in matcher.feed(text) if isinstance(ev, Recorded)]
    assert [r.point.number for r in recorded] == list(range(1, grid.size + 1))
    for r in recorded:
        expected = a * r.point.x + b * r.point.y
        assert abs(r.z - expected) <= grid.units.resolution / 2 + 1e-9
    assert matcher.complete
    assert machine.variables[5223] == -3.0


@given(st.lists(st.text(max_size=60), max_size=30))
def test_matcher_takes_any_text(lines: list[str]) -> None:
    matcher = PointMatcher(Grid(3, 3, 0.5, 0.5))
    for text in lines:
        matcher.feed(text)
    assert set(matcher.values) <= set(range(1, 10))


csv_text = st.lists(
    st.one_of(
        st.text(alphabet='0123456789.,-+exyzXYZ# \t"abc', max_size=40),
        st.just("x,y,z"),
        st.just("# grid 3x3 pitch 0.5,0.5 origin 0,0 units inch"),
        st.just("# grid 1x1 pitch 0,0 origin 0,0 units inch"),
        st.just("# grid 3x3 pitch nan,1 origin 0,0 units parsec"),
    ),
    max_size=12,
).map("\n".join)


@settings(deadline=None)
@given(csv_text)
def test_points_and_height_map_files_fail_only_with_typed_errors(text: str) -> None:
    import tempfile
    from pathlib import Path

    from opendnc.errors import InputError
    from opendnc.sim.haas import parse_surface
    from opendnc.surface.points import read_points

    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "f.csv"
        path.write_text(text)
        with contextlib.suppress(InputError):
            read_points(path)
        with contextlib.suppress(InputError):
            parse_surface(f"csv:{path}")
