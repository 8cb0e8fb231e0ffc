"""Property tests of the preview's decimation and binary form: any path keeps its shape
within the tolerance, the binary reads back, and garbage is refused with InputError only."""

from __future__ import annotations

import contextlib
import itertools
import math

from hypothesis import given, settings
from hypothesis import strategies as st

from opendnc.errors import InputError
from opendnc.nccheck import Move, MoveKind, Plane
from opendnc.nccheck.backplot import build, decode, encode

coordinate = st.floats(-500, 500, allow_nan=False).map(lambda v: round(v, 3))
point = st.tuples(coordinate, coordinate, coordinate)


@st.composite
def paths(draw: st.DrawFn) -> list[Move]:
    """Connected stretches of straight moves (and some arcs), with jumps between them."""
    moves: list[Move] = []
    here = draw(point)
    for line in range(1, draw(st.integers(0, 60)) + 1):
        if draw(st.booleans()) and draw(st.integers(0, 9)) == 0:
            here = draw(point)  # the path starts again elsewhere
        kind = draw(st.sampled_from([MoveKind.RAPID, MoveKind.FEED, MoveKind.FEED]))
        tool = draw(st.sampled_from(["1", "2", None]))
        if draw(st.integers(0, 4)) == 0:
            radius = draw(st.floats(0.01, 50))
            angle = draw(st.floats(0, 2 * math.pi))
            centre = (here[0] - radius * math.cos(angle), here[1] - radius * math.sin(angle), 0.0)
            turn = draw(st.floats(0, 2 * math.pi))
            end = (
                centre[0] + radius * math.cos(angle + turn),
                centre[1] + radius * math.sin(angle + turn),
                here[2] + draw(st.floats(-5, 5)),
            )
            arc = draw(st.sampled_from([MoveKind.ARC_CW, MoveKind.ARC_CCW]))
            moves.append(Move(arc, here, end, line, tool, centre, Plane.XY))
        else:
            end = draw(point) if draw(st.booleans()) else (here[0] + 0.01, here[1], here[2])
            moves.append(Move(kind, here, end, line, tool))
        here = end
    return moves


def _distance_to_segment(p: tuple[float, ...], a: tuple[float, ...], b: tuple[float, ...]) -> float:
    ab = [b[i] - a[i] for i in range(3)]
    ap = [p[i] - a[i] for i in range(3)]
    length2 = sum(v * v for v in ab)
    t = 0.0 if length2 == 0 else max(0.0, min(1.0, sum(ab[i] * ap[i] for i in range(3)) / length2))
    return math.dist(p, [a[i] + t * ab[i] for i in range(3)])


@settings(max_examples=60, deadline=None)
@given(paths(), st.sampled_from([None, 0.05, 0.5, 5.0]))
def test_every_end_point_stays_within_twice_the_tolerance(
    moves: list[Move], tolerance: float | None
) -> None:
    plot = build(moves, tolerance=tolerance)
    segments = []
    for run in plot.runs:
        kept = plot.run_points(run)
        segments += list(itertools.pairwise(kept)) if len(kept) > 1 else [(kept[0], kept[0])]
    # float32 coordinates: a relative 1e-7 of the largest value, plus the tolerance's bound
    slack = 2 * plot.tolerance * (1 + 1e-9) + 1e-4
    for move in moves:
        for p in (move.start, move.end):
            nearest = min(_distance_to_segment(p, a, b) for a, b in segments)
            assert nearest <= slack, (p, nearest, plot.tolerance)
    back = decode(encode(plot))
    assert back.runs == plot.runs
    assert list(back.points) == list(plot.points)


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=200))
def test_decode_refuses_garbage_with_input_error_only(data: bytes) -> None:
    with contextlib.suppress(InputError):
        decode(b"ODTP\x01\x00\x00\x00" + data)
    with contextlib.suppress(InputError):
        decode(data)
