"""Mapping DPRNT lines to grid points: missing, repeated, out of order, resume, the file."""

from __future__ import annotations

from datetime import UTC, datetime
from pathlib import Path

import pytest

from opendnc.errors import InputError
from opendnc.haas.dprnt import parse_line
from opendnc.haas.listen import CapturedLine
from opendnc.surface.capture import (
    CaptureSession,
    Ignored,
    Mismatch,
    Missing,
    OutOfOrder,
    PointMatcher,
    Recorded,
    Repeated,
    RunEnded,
    RunStarted,
)
from opendnc.surface.grid import Grid, Units
from opendnc.surface.points import PointsWriter, read_points

GRID = Grid(3, 2, 0.5, 0.5)  # points 1..3 along Y0, 4..6 back along Y0.5


def line(number: int, z: float, grid: Grid = GRID) -> str:
    p = grid.point(number)
    return f"P{number} X{p.x:9.4f} Y{p.y:9.4f} Z{z:9.4f}"


def test_in_order_run_records_every_point() -> None:
    matcher = PointMatcher(GRID)
    assert matcher.feed("SURFACE START ZOFFSET  -5.0000") == [
        RunStarted("SURFACE START ZOFFSET  -5.0000")
    ]
    for n in range(1, 7):
        (event,) = matcher.feed(line(n, n / 1000))
        assert isinstance(event, Recorded)
        assert event.point.number == n
    assert matcher.complete
    assert matcher.feed("SURFACE END") == [RunEnded(())]


def test_missing_line_is_reported_never_shifted() -> None:
    matcher = PointMatcher(GRID)
    matcher.feed(line(1, 0.001))
    matcher.feed(line(2, 0.002))
    events = matcher.feed(line(4, 0.004))  # 3 was lost
    assert events[0] == Missing((3,), 4)
    assert isinstance(events[1], Recorded)
    assert events[1].point.number == 4
    assert matcher.values == {1: 0.001, 2: 0.002, 4: 0.004}
    matcher.feed(line(5, 0.005))
    matcher.feed(line(6, 0.006))
    assert not matcher.complete
    assert matcher.missing() == (3,)
    assert matcher.feed("SURFACE END") == [RunEnded((3,))]


def test_lost_tail_reported_at_the_end() -> None:
    matcher = PointMatcher(GRID)
    for n in (1, 2, 3, 4):
        matcher.feed(line(n, 0.0))
    assert matcher.feed("SURFACE END") == [Missing((5, 6), 7), RunEnded((5, 6))]


def test_repeated_and_out_of_order() -> None:
    matcher = PointMatcher(GRID)
    matcher.feed(line(1, 0.001))
    matcher.feed(line(3, 0.003))
    assert matcher.feed(line(3, 0.003)) == [Repeated(3, 0.003, 0.003, True)]
    assert matcher.feed(line(1, 0.002)) == [Repeated(1, 0.002, 0.001, False)]
    events = matcher.feed(line(2, 0.002))  # the missing point arrives late
    assert events[0] == OutOfOrder(2, 3)
    assert isinstance(events[1], Recorded)
    assert matcher.values[1] == 0.001  # the first reading is kept


def test_lines_that_do_not_fit_are_not_stored() -> None:
    matcher = PointMatcher(GRID)
    assert matcher.feed("DONE") == [Ignored("DONE")]
    assert matcher.feed("P2 X 0.5 Y 0.0") == [Ignored("P2 X 0.5 Y 0.0")]  # no Z
    (wrong_xy,) = matcher.feed("P2 X   0.5000 Y   0.5000 Z 0.1")
    assert isinstance(wrong_xy, Mismatch)
    assert "grid has it at X0.5 Y0" in wrong_xy.reason
    (off_grid,) = matcher.feed("P7 X 0 Y 0 Z 0")
    assert isinstance(off_grid, Mismatch)
    assert "not on the 3x2 grid" in off_grid.reason
    (fraction,) = matcher.feed("P1.5 X 0 Y 0 Z 0")
    assert isinstance(fraction, Mismatch)
    assert matcher.values == {}


def test_restart_begins_the_order_check_again() -> None:
    matcher = PointMatcher(GRID)
    for n in (1, 2):
        matcher.feed(line(n, 0.0))
    matcher.feed("SURFACE START ZOFFSET 0")
    # a rerun repeats 1 and 2 (already stored, kept), then fills the rest without complaint
    events = [e for n in range(1, 7) for e in matcher.feed(line(n, 0.0))]
    assert not [e for e in events if isinstance(e, Missing | OutOfOrder | Repeated)]
    assert matcher.complete


def captured(text: str) -> CapturedLine:
    return CapturedLine(datetime(2026, 1, 2, 3, 4, 5, tzinfo=UTC), text, parse_line(text).fields)


def test_session_writes_rows_as_printed_and_resume_reads_them(tmp_path: Path) -> None:
    path = tmp_path / "points.csv"
    done: list[bool] = []
    with PointsWriter(path, GRID) as writer:
        session = CaptureSession(GRID, writer, done=lambda: done.append(True))
        session.feed(captured("P1 X   0.0000 Y   0.0000 Z  -0.0120"))
        session.feed(captured("P3 X   1.0000 Y   0.0000 Z   0.0300"))
        # each row is on disk before the next line is read
        assert path.read_text().count("\n") == 4
    points = read_points(path)
    assert points.grid == GRID
    assert [(r.point, r.row, r.col, r.x, r.y, r.z_text) for r in points.rows] == [
        (1, 1, 1, 0.0, 0.0, "-0.0120"),
        (3, 1, 3, 1.0, 0.0, "0.0300"),
    ]
    assert points.rows[0].time == "2026-01-02T03:04:05+00:00"
    assert session.report.captured == 2
    assert not done
    with pytest.raises(InputError, match="--resume"):
        PointsWriter(path, GRID)
    with PointsWriter(path, GRID, resume=True) as writer:
        session = CaptureSession(GRID, writer, done=lambda: done.append(True))
        for row in read_points(path).rows:
            session.matcher.preload(row.point, row.z)
        for n in range(1, 7):
            session.feed(captured(line(n, 0.5)))
    assert done == [True]
    rows = read_points(path).rows
    assert sorted(r.point for r in rows) == [1, 2, 3, 4, 5, 6]
    assert [r.z for r in rows if r.point == 1] == [-0.012]  # not overwritten by the rerun


def test_read_points_errors(tmp_path: Path) -> None:
    bad = tmp_path / "bad.csv"
    bad.write_text("a,b\n1,2\n")
    with pytest.raises(InputError, match="no column x, y, z"):
        read_points(bad)
    bad.write_text("x,y,z\n1,2,three\n")
    with pytest.raises(InputError, match="row 2"):
        read_points(bad)
    bad.write_bytes(b"\xff\xfe\x00")
    with pytest.raises(InputError, match="not a text"):
        read_points(bad)
    with pytest.raises(InputError, match="cannot read"):
        read_points(tmp_path / "nope.csv")
    plain = tmp_path / "plain.csv"
    plain.write_text("x,y,z\n0,0,1\n1,0,2\n")
    points = read_points(plain)
    assert points.grid is None
    assert [r.point for r in points.rows] == [1, 2]


def test_grid_comment_round_trip(tmp_path: Path) -> None:
    grid = Grid(5, 4, 2.5, 3.0, -10.0, 7.5, Units.MM)
    path = tmp_path / "mm.csv"
    PointsWriter(path, grid).close()
    assert read_points(path).grid == grid
