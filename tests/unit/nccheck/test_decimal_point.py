"""Numbers written without a decimal point: a dwell's P in milliseconds, axis words in the
least input increment (Haas, Fanuc), and a lathe program checked as a mill program
(docs/check.md#decimal-point). Expected values are worked out by hand in the comments."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from opendnc.nccheck import CheckResult, MachineLimits, check_text

LATHE_0100 = Path(__file__).parents[2] / "data/corpus/real/fanuc-lathe/gcodeworkshop/0100.nc"


def run(body: str, dialect: str | None = None) -> CheckResult:
    machine = MachineLimits(dialect=dialect) if dialect else None
    return check_text(f"%\nO01000\n{body}\n%\n", machine=machine)


@pytest.mark.parametrize("dialect", [None, "haas-mill", "fanuc-mill", "fanuc-lathe"])
def test_a_dwell_p_without_a_point_counts_milliseconds(dialect: str | None) -> None:
    # no move at all: the time is the dwells only; 200 ms + 2000 ms + 6000 ms = 8.2 s
    result = run("G04 P200\nG04 P2000\nG4 P6000\nM30", dialect)
    assert result.cycle_time_s == pytest.approx(8.2)


@pytest.mark.parametrize("dialect", [None, "haas-mill", "fanuc-mill"])
def test_a_dwell_with_a_point_counts_seconds(dialect: str | None) -> None:
    # P2. is 2 s (Haas); X1.5 is 1.5 s; X1500 (no point) is 1500 ms = 1.5 s: 5 s in all
    result = run("G04 P2.\nG04 X1.5\nG04 X1500\nM30", dialect)
    assert result.cycle_time_s == pytest.approx(5.0)


def test_a_lathe_dwell_may_be_given_as_u() -> None:
    assert run("G04 U0.5\nM30", "fanuc-lathe").cycle_time_s == pytest.approx(0.5)


def test_a_drilling_cycles_dwell_p_counts_milliseconds() -> None:
    body = "G21 G90\nT1 M06\nG00 X0. Y0. S1000 M03\nG43 H01 Z10.\n{cycle}\nG80\nM30"
    with_dwell = run(body.format(cycle="G82 X5. Y5. Z-2. R1. P500 F100.\nX15."), "haas-mill")
    no_dwell = run(body.format(cycle="G82 X5. Y5. Z-2. R1. F100.\nX15."), "haas-mill")
    # two holes, 500 ms each: 1 s more
    assert with_dwell.cycle_time_s - no_dwell.cycle_time_s == pytest.approx(1.0)


def test_a_whole_number_axis_word_counts_in_the_least_increment() -> None:
    body = "G21 G90\nT1 M06\nG00 X0. Y0. Z0. S1000 M03\nG01 X100 F100.\nM30"
    result = run(body, "fanuc-mill")
    # X100 without a point: 100 x 0.001 mm = 0.1 mm of feed
    assert result.feed_distance == pytest.approx(0.1)
    assert [(p.line, p.severity.value) for p in result.problems] == [(6, "warning")]
    assert "X100 has no decimal point" in result.problems[0].message
    inch = run(body.replace("G21", "G20").replace("F100.", "F10."), "fanuc-mill")
    assert inch.feed_distance == pytest.approx(0.01)  # 100 x 0.0001 inch


def test_haas_reads_a_whole_number_feed_in_the_increment_and_fanuc_does_not() -> None:
    body = "G21 G90\nT1 M06\nG00 X0. Y0. Z0. S1000 M03\nG01 X10. F100\nM30"
    # Fanuc: 10 mm at 100 mm/min = 0.1 min = 6 s; Haas (setting 77 off): F100 is
    # 0.1 mm/min, 10 mm take 100 min = 6000 s; the rapid from X0 Y0 Z0 is nothing
    assert run(body, "fanuc-mill").cycle_time_s == pytest.approx(6.0 + 4.0)  # + tool change
    assert run(body, "haas-mill").cycle_time_s == pytest.approx(6000.0 + 4.0)


def test_a_real_lathe_programs_dwells_are_milliseconds() -> None:
    text = LATHE_0100.read_text()
    machine = MachineLimits(dialect="fanuc-lathe")
    without = re.sub(r"(?m)^G0?4P\d+ *$", "", text)
    assert without.count("\n") == text.count("\n")  # the lines stay, only their text goes
    dwell = (
        check_text(text, machine=machine).cycle_time_s
        - check_text(without, machine=machine).cycle_time_s
    )
    # G4P200, G04P2000, G4P6000: 0.2 + 2 + 6 = 8.2 s (it was read as 8,200 s)
    assert dwell == pytest.approx(8.2)


def test_a_lathe_program_checked_as_a_mill_is_flagged() -> None:
    result = check_text(LATHE_0100.read_text(), machine=MachineLimits(dialect="fanuc-mill"))
    found = {(p.line, p.severity.value): p.message for p in result.problems}
    # line 27 "G1U-4.6Z[#503+.3]F0.2" is the first lathe-only block (U on a G01)
    assert "lathe block" in found[(27, "warning")]
    # the program never gives Y: its feed moves cannot be measured, and that is said
    assert any("never gives the Y position" in m for m in found.values())
    lathe = check_text(LATHE_0100.read_text(), machine=MachineLimits(dialect="fanuc-lathe"))
    assert lathe.problems == ()
    assert lathe.move_count > 0
