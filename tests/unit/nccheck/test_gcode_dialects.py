"""G-code dialects, lathe mode, and how a run goes on and ends (docs/check.md#g-code)."""

from __future__ import annotations

import math

import pytest

from opendnc.errors import InputError
from opendnc.nccheck import Budget, CheckResult, MachineLimits, Units, check_text
from opendnc.nccheck.dialects import DIALECTS, dialect_named, guess_dialect
from opendnc.nccheck.result import MAX_PROBLEMS


def run(body: str, dialect: str | None = None, **kwargs: object) -> CheckResult:
    machine = MachineLimits(dialect=dialect) if dialect else None
    text = f"%\nO01000\n{body}\n%\n"
    return check_text(text, machine=machine, **kwargs)  # type: ignore[arg-type]


def messages(result: CheckResult) -> list[tuple[int, str, str]]:
    return [(p.line, p.severity.value, p.message) for p in result.problems]


MILL = "G21 G90 G17\nT1 M06\nG00 G54 X0. Y0.\nG43 H01 Z5.\n"


def test_a_spindle_started_in_the_block_of_the_cut_is_running_for_it() -> None:
    result = run(MILL + "G01 Z-1. F300. S6000 M03\nX10.\nM30")
    assert result.problems == ()


def test_named_controls_keep_to_their_own_codes() -> None:
    body = MILL + "S6000 M03\nG54.1 P1\nG01 Z-1. F300.\nM30"
    assert run(body, "fanuc-mill").problems == ()
    assert run(body).problems == ()  # not named: Haas and Fanuc codes of a mill
    assert messages(run(body, "haas-mill")) == [
        (8, "error", "G54.1 is not a G code of the Haas mill control")
    ]


def test_g54_1_selects_the_additional_offset_as_g154_does() -> None:
    offsets = {"G110": {"X": -100.0, "Y": -50.0, "Z": -200.0}}
    machine = MachineLimits(dialect="fanuc-mill", work_offsets=offsets)
    text = "%\nO01000\nG21 G90\nG54.1 P1\nG00 X10. Y10. Z5.\nM30\n%\n"
    result = check_text(text, machine=machine)
    assert result.end.machine_position == {"X": -90.0, "Y": -40.0, "Z": -195.0}


def test_the_millisecond_timer_may_be_reset() -> None:
    result = run("G21\n#3001 = 0\n#100 = #3001\nG04 P2.\n#101 = #3001\nM30")
    assert result.problems == ()
    assert result.end.variables[100] == 0.0
    assert result.end.variables[101] == 2000.0  # the dwell's two seconds


def test_fanuc_alarms_are_3000_plus_n() -> None:
    result = run("#3000 = 5 (CHECK OFFSETS)\nM30", "fanuc-mill")
    assert messages(result) == [(3, "error", "the program raises alarm 3005 (CHECK OFFSETS)")]


def test_rigid_tapping_turns_the_spindle_itself_on_fanuc() -> None:
    body = MILL + "M29 S500\nG84 X10. Y10. Z-10. R2. F625.\nG80\nM30"
    assert run(body, "fanuc-mill").problems == ()
    result = run(body.replace("M29 S500", "S500"), "fanuc-mill")  # conventional: stopped
    assert messages(result) == [(8, "error", "a tap (G84) with the spindle stopped")]


@pytest.mark.parametrize("dialect", ["haas-mill", "haas-lathe", "mill", "lathe", None])
def test_a_haas_tap_starts_the_spindle_itself(dialect: str | None) -> None:
    # Haas G84: "not necessary to start the spindle CW before this canned cycle"; the guessed
    # union takes what a Haas takes
    lathe = dialect is not None and "lathe" in dialect
    head = "G21 G99\nT0303\nG97 S400\nG00 X0. Z5.\n" if lathe else MILL + "S500\n"
    body = head + "G84 Z-10. R2. F1.25\nG80\nM30"
    result = run(body, dialect)
    assert not any("spindle stopped" in p.message for p in result.problems), messages(result)
    fanuc = run(body, "fanuc-lathe" if lathe else "fanuc-mill")  # no M29, no M03: stopped
    assert any("a tap (G84) with the spindle stopped" in p.message for p in fanuc.errors)


def test_a_lathe_turns_diameters_and_surface_speed_into_time() -> None:
    # G96 S200 at diameter 40 is 200000 / (pi * 40) = 1592 rpm, clamped by G50 S1000 to
    # 1000 rpm; 0.2 mm per revolution is 200 mm/min: 20 mm of Z take 6 s, the tool change 4 s
    body = "G21 G99\nT0101\nG50 S1000\nG96 S200 M03\nG00 X40. Z0.\nG01 Z-20. F0.2\nM30"
    result = run(body, "fanuc-lathe")
    assert result.problems == ()
    assert result.extents["X"] == (20.0, 20.0)  # the radius of the diameter 40
    assert result.cycle_time_s == pytest.approx(4.0 + 6.0, abs=0.01)
    # without the clamp the same cut runs at 1592 rpm
    unclamped = run(body.replace("G50 S1000\n", ""), "fanuc-lathe")
    rpm = 200_000 / (math.pi * 40)
    assert unclamped.cycle_time_s == pytest.approx(4.0 + 20 / (0.2 * rpm) * 60, abs=0.01)


def test_u_and_w_are_incremental_on_a_lathe() -> None:
    body = "G21 G99\nT0101\nG97 S1000 M03\nG00 X40. Z2.\nG01 W-22. F0.2\nU-10.\nM30"
    result = run(body, "haas-lathe")
    assert result.problems == ()
    assert result.end.position == {"X": 15.0, "Y": 0.0, "Z": -20.0}


def test_a_lathe_program_is_guessed_from_its_words() -> None:
    assert guess_dialect("G50 S2000\nG96 S180 M03\n").lathe
    assert guess_dialect("G71 P10 Q20 U0.5 W0.1 F0.3\n").lathe
    assert not guess_dialect("(G96 IN A COMMENT)\nG01 X1. F100.\n").lathe
    assert not guess_dialect("G01 X1. Y2. F100.\n").lathe


def test_dialect_names() -> None:
    assert set(DIALECTS) >= {"haas-mill", "haas-lathe", "fanuc-mill", "fanuc-lathe"}
    assert dialect_named("FANUC_LATHE").name == "fanuc-lathe"
    with pytest.raises(InputError, match="unknown control 'okuma'"):
        dialect_named("okuma")


def test_the_run_goes_on_after_a_runtime_error() -> None:
    body = MILL + "S6000 M03\n#1 = 1 / 0\nG01 Z-1. F300.\nG02 X10. R2.\nG01 X20.\nM05\nX30.\nM30"
    result = run(body)
    assert [(line, severity) for line, severity, _ in messages(result)] == [
        (8, "error"),  # division by zero
        (10, "error"),  # R too small for the chord
        (13, "error"),  # the cut after M05: found although two errors came before it
    ]
    assert result.end.ended


def test_problems_are_capped_with_a_count_of_the_rest() -> None:
    body = "\n".join(f"#{100 + i % 50} = {i} / 0" for i in range(MAX_PROBLEMS + 50)) + "\nM30"
    result = run(body)
    assert len(result.problems) == MAX_PROBLEMS
    assert (result.more_problems, result.more_errors) == (50, 50)
    assert not result.ok


def test_a_run_stopped_by_its_budget_is_an_error() -> None:
    # a straight program runs each block once, outside the block budget (which is for
    # loops): only the time budget can stop it, and a stop is an error naming it
    body = "G21 G90\n" + "G00 X1.\nG00 X2.\n" * 2000 + "M30"
    assert run(body, budget=Budget(blocks=2048)).ok
    result = run(body, budget=Budget(seconds=0.0))
    assert not result.ok
    (problem,) = result.errors
    assert "after 1,024 blocks (its budget of 0 s of CPU ran out)" in problem.message
    assert "the rest of the program is not checked" in problem.message


def test_a_title_comment_before_the_leading_percent_is_not_the_program() -> None:
    text = "(POST: FUSION 360)\n%\nO01000\nG21\nM30\n%\n"
    result = check_text(text)
    assert result.problems == ()
    assert result.end.ended


def test_one_message_per_missing_called_program() -> None:
    result = run("G65 P9810 Z10.\nG65 P9810 Z20.\nM30")
    assert messages(result) == [(3, "warning", "calls O09810, which is not in the library")]


def test_the_rapid_rate_is_taken_in_the_travel_units() -> None:
    # 1000 in/min is 25,400 mm/min: 254 mm of rapid take 0.6 s
    machine = MachineLimits(rapid_rate=1000.0, travel={"Z": (-500.0, 500.0)}, travel_units=None)
    inch = MachineLimits(rapid_rate=1000.0, travel={"Z": (-20.0, 20.0)}, travel_units=Units.INCH)
    text = "%\nO01000\nG21\nG00 X0. Y0. Z0.\nG00 Z254.\nM30\n%\n"
    assert check_text(text, machine=inch).cycle_time_s == pytest.approx(0.6)
    # without units the rate is in the program's: 1000 mm/min, 15.24 s
    assert check_text(text, machine=machine).cycle_time_s == pytest.approx(15.24)


def test_lathe_cycles_bring_the_tool_back() -> None:
    # G74-G76 and the single cycles G90/G92/G94 end where they started: their X/Z are the
    # cycle's end point, not a move
    body = (
        "G21 G99\nT0101\nG97 S800 M03\nG00 X40. Z5.\n"
        "G76 P020060 Q100 R0.05\nG76 X33.8 Z-18. P1100 Q350 F1.75\n"
        "G74 Z-30. Q5000 F0.1\nG90 X30. Z-20. F0.2\nX28.\nG00 X40. Z5.\nM30"
    )
    result = run(body, "fanuc-lathe")
    assert result.errors == ()
    assert result.extents["Z"] == (5.0, 5.0)
    assert result.end.position == {"X": 20.0, "Y": 0.0, "Z": 5.0}


def test_probe_moves_are_made_with_the_spindle_stopped() -> None:
    body = MILL + "G31 Z-10. F500.\nG00 Z5.\nM30"
    assert run(body).errors == ()


def test_a_missing_called_program_may_have_started_the_spindle() -> None:
    body = MILL + "G65 P9000 T2 (THE SHOP'S TOOL CHANGE MACRO)\nG01 Z-1. F300.\nM30"
    result = run(body)
    assert result.errors == ()
    assert [p.message for p in result.warnings] == ["calls O09000, which is not in the library"]
