"""The preview's decimation and binary form (opendnc.nccheck.backplot), on paths worked out
by hand: what must stay (corners, reversals, run ends), what may go (points on a straight
line), arcs cut within the tolerance, and the binary layout read field by field."""

from __future__ import annotations

import itertools
import math
import struct

import pytest

from opendnc.errors import InputError
from opendnc.nccheck import Move, MoveKind, Plane, check_text
from opendnc.nccheck.backplot import (
    MAGIC,
    NO_TOOL,
    Backplot,
    build,
    decode,
    default_tolerance,
    encode,
)


def feed(a: tuple[float, float, float], b: tuple[float, float, float], line: int = 1) -> Move:
    return Move(MoveKind.FEED, a, b, line, tool="1")


def chain(points: list[tuple[float, float, float]], kind: MoveKind = MoveKind.FEED) -> list[Move]:
    return [
        Move(kind, a, b, i + 1, tool="1") for i, (a, b) in enumerate(itertools.pairwise(points))
    ]


def test_a_straight_line_of_many_moves_is_two_points() -> None:
    points = [(i * 0.01, 0.0, 0.0) for i in range(1001)]
    plot = build(chain(points), tolerance=0.001)
    assert len(plot.runs) == 1
    assert plot.run_points(plot.runs[0]) == [(0.0, 0.0, 0.0), pytest.approx((10.0, 0.0, 0.0))]
    # the lines of the kept points: the first move's, and the last one's
    assert list(plot.lines) == [1, 1000]


def test_a_corner_and_a_reversal_are_kept() -> None:
    # along X, a right angle to Y, then straight back down Y (a peck's reversal)
    points = [(0.0, 0.0, 0.0), (5.0, 0.0, 0.0), (10.0, 0.0, 0.0), (10.0, 5.0, 0.0)]
    points += [(10.0, 10.0, 0.0), (10.0, 2.0, 0.0)]
    plot = build(chain(points), tolerance=0.01)
    kept = plot.run_points(plot.runs[0])
    assert kept == [(0.0, 0.0, 0.0), (10.0, 0.0, 0.0), (10.0, 10.0, 0.0), (10.0, 2.0, 0.0)]


def test_a_wiggle_within_the_tolerance_goes_and_one_beyond_it_stays() -> None:
    small = [(0.0, 0.0, 0.0), (5.0, 0.004, 0.0), (10.0, 0.0, 0.0)]
    assert len(build(chain(small), tolerance=0.01).lines) == 2
    large = [(0.0, 0.0, 0.0), (5.0, 0.5, 0.0), (10.0, 0.0, 0.0)]
    assert len(build(chain(large), tolerance=0.01).lines) == 3


def test_runs_split_at_a_tool_a_kind_and_a_gap() -> None:
    moves = [
        Move(MoveKind.RAPID, (0, 0, 10), (0, 0, 1), 1, tool="1"),
        Move(MoveKind.FEED, (0, 0, 1), (0, 0, -2), 2, tool="1"),
        Move(MoveKind.FEED, (0, 0, -2), (5, 0, -2), 3, tool="1"),
        Move(MoveKind.FEED, (5, 0, -2), (5, 5, -2), 4, tool="2"),  # another tool
        Move(MoveKind.FEED, (9, 9, -2), (9, 0, -2), 5, tool="2"),  # starts elsewhere
        Move(MoveKind.FEED, (9, 0, -2), (0, 0, -2), 6, tool=None),  # no tool loaded
    ]
    plot = build(moves, tools=["1", "2"], tolerance=0.001)
    shape = [(r.rapid, r.tool, r.count) for r in plot.runs]
    assert shape == [(True, 0, 2), (False, 0, 3), (False, 1, 2), (False, 1, 2), (False, -1, 2)]
    assert plot.tools == ("1", "2")


def test_a_full_circle_is_cut_into_chords_within_the_tolerance() -> None:
    radius, tol = 10.0, 0.01
    circle = Move(
        MoveKind.ARC_CCW, (10.0, 0.0, 0.0), (10.0, 0.0, 0.0), 7, "1", (0.0, 0.0, 0.0), Plane.XY
    )
    plot = build([circle], tolerance=tol)
    kept = plot.run_points(plot.runs[0])
    # every point on the circle, the path closed, counter-clockwise (y grows first)
    assert all(math.hypot(x, y) == pytest.approx(radius, abs=1e-5) for x, y, _ in kept)
    assert kept[0] == kept[-1] == (10.0, 0.0, 0.0)
    assert kept[1][1] > 0
    # each chord's middle within the tolerance of the circle: the sagitta
    for (x0, y0, _), (x1, y1, _) in itertools.pairwise(kept):
        assert radius - math.hypot((x0 + x1) / 2, (y0 + y1) / 2) <= tol + 1e-6
    # and not much finer than needed: a sagitta of tol / 2 needs 2 pi / (2 acos(1 - 0.0005))
    assert len(kept) - 1 <= 2 * math.ceil(math.pi / math.acos(1 - tol / 2 / radius))


def test_a_clockwise_helix_in_the_zx_plane_descends_along_y() -> None:
    # G18: the arc turns in Z-X, the third axis is Y; a half turn clockwise from +Z to -Z
    helix = Move(
        MoveKind.ARC_CW, (0.0, 0.0, 5.0), (0.0, -4.0, -5.0), 3, "1", (0.0, 0.0, 0.0), Plane.ZX
    )
    plot = build([helix], tolerance=0.01)
    kept = plot.run_points(plot.runs[0])
    assert kept[-1] == (0.0, -4.0, -5.0)
    middle = kept[len(kept) // 2]
    # Z x X = Y: seen from +Y the plane turns from Z to X counter-clockwise, so clockwise
    # from +Z goes through -X
    assert middle[0] == pytest.approx(-5.0, abs=0.05)
    assert middle[1] == pytest.approx(-2.0, abs=0.05)


def test_the_point_budget_doubles_the_tolerance_until_it_fits() -> None:
    # a zig-zag of 20,000 points that no tolerance below 1 may drop
    points = [(i * 0.1, float(i % 2), 0.0) for i in range(20_000)]
    plot = build(chain(points), tolerance=0.01, max_points=500)
    assert plot.point_count <= 500
    assert plot.tolerance >= 0.5  # what it took (a zig-zag of height 1)
    assert build(chain(points), tolerance=0.01).point_count == 20_000


def test_the_default_tolerance_is_the_diagonal_over_4000() -> None:
    moves = chain([(0.0, 0.0, 0.0), (300.0, 0.0, 0.0), (300.0, 400.0, 0.0)])
    assert default_tolerance(moves) == pytest.approx(500.0 / 4000)
    assert default_tolerance(moves, {"X": (0.0, 30.0), "Y": (0.0, 40.0)}) == pytest.approx(
        50.0 / 4000
    )
    assert default_tolerance([]) == 1e-3


def test_the_binary_layout_field_by_field() -> None:
    moves = [
        Move(MoveKind.RAPID, (0, 0, 5), (1, 2, 5), 4, tool=None),
        Move(MoveKind.FEED, (1, 2, 5), (1, 2, -1), 5, tool="7"),
    ]
    data = encode(build(moves, tools=["7"], tolerance=0.001, meta={"units": "mm"}))
    magic, version, meta_len, runs, points = struct.unpack_from("<4sIIII", data)
    assert (magic, version, runs, points) == (MAGIC, 1, 2, 4)
    assert meta_len % 4 == 0
    meta = data[20 : 20 + meta_len].decode().rstrip()
    assert meta == '{"moves":2,"tolerance":0.001,"tools":["7"],"units":"mm"}'
    at = 20 + meta_len
    assert struct.unpack_from("<8I", data, at) == (0, 2, 1, NO_TOOL, 2, 2, 0, 0)
    at += 32
    xyz = struct.unpack_from("<12f", data, at)
    assert xyz == (0, 0, 5, 1, 2, 5, 1, 2, 5, 1, 2, -1)
    assert struct.unpack_from("<4I", data, at + 48) == (4, 4, 5, 5)
    assert len(data) == at + 48 + 16


def test_decode_reads_back_what_encode_wrote() -> None:
    result = check_text("%\nO1\nT1 M06\nG00 X0 Y0 Z5\nG01 Z-1 F100\nG02 X10 Y0 R5\nM30\n%\n")
    plot = build(result.moves, tools=[t.tool for t in result.tools], meta={"units": "mm"})
    back = decode(encode(plot))
    assert back.runs == plot.runs
    assert list(back.points) == list(plot.points)
    assert list(back.lines) == list(plot.lines)
    assert (back.tools, back.moves, back.tolerance) == (plot.tools, plot.moves, plot.tolerance)
    assert back.meta == {"units": "mm"}


@pytest.mark.parametrize(
    ("data", "reason"),
    [
        (b"", "at least 20 bytes"),
        (b"ODTX" + bytes(16), "not a toolpath"),
        (struct.pack("<4sIIII", MAGIC, 2, 0, 0, 0), "format 2"),
        (struct.pack("<4sIIII", MAGIC, 1, 0, 1, 0), "36 bytes, got 20"),
        (struct.pack("<4sIIII", MAGIC, 1, 4, 0, 0) + b"[]  ", "not a JSON object"),
        (struct.pack("<4sIIII", MAGIC, 1, 4, 0, 0) + b"\xff   ", "not JSON"),
        (
            struct.pack("<4sIIII", MAGIC, 1, 4, 1, 1) + b"{}  " + struct.pack("<4I", 0, 2, 0, 0)
            + bytes(16),
            "run 0 points outside",
        ),
    ],
)  # fmt: skip
def test_decode_refuses_what_is_not_a_toolpath(data: bytes, reason: str) -> None:
    with pytest.raises(InputError, match=reason):
        decode(data)


def test_a_path_of_no_move_is_empty() -> None:
    plot = build([])
    assert (plot.runs, plot.point_count) == ((), 0)
    assert isinstance(decode(encode(plot)), Backplot)
