"""How a Klartext dry run goes on and ends: errors end their block only, the problem list is
capped with a count of the rest, and a budget that stops a run is an error."""

from __future__ import annotations

import math
import re

import pytest

from opendnc.nccheck import MAX_PROBLEMS, Budget, check_text


def program(*body: str) -> str:
    lines = ["BEGIN PGM T MM", "TOOL CALL 1 Z S1000 F100", "L X+0 Y+0 Z+0 R0 FMAX M3", *body]
    lines += ["M30", "END PGM T MM"]
    return "\n".join(f"{n} {text}" for n, text in enumerate(lines)) + "\n"


def test_every_problem_is_reported_up_to_the_cap_and_the_rest_counted() -> None:
    # each C has no circle centre: a runtime error of its own block, and the run goes on
    result = check_text(program(*(f"C X+{n} Y+0 DR+" for n in range(1, 301))))
    assert len(result.problems) == MAX_PROBLEMS
    assert result.more_problems == 300 - MAX_PROBLEMS
    assert result.more_errors == 300 - MAX_PROBLEMS
    assert {p.line for p in result.problems} == set(range(4, 4 + MAX_PROBLEMS))  # file lines 4 on
    assert result.end.ended  # the run reached M30
    assert result.to_dict()["more_problems"] == 100
    assert not result.ok


def test_a_long_program_without_loops_runs_to_its_end() -> None:
    moves = [f"L X+{n % 50} Y+{n % 7} F100" for n in range(3000)]
    result = check_text(program(*moves), budget=Budget(blocks=1000))
    assert result.errors == ()
    assert result.end.ended
    assert result.blocks == 3 + 3000 + 1  # up to M30


def test_a_block_budget_that_stops_a_run_is_an_error() -> None:
    # calls are not jumps back: 200 calls of a 100-block label exceed 1,000 blocks
    label = [f"L X+{n % 50} F100" for n in range(100)]
    body = ["CALL LBL 1"] * 200 + ["M30", "LBL 1", *label, "LBL 0"]
    result = check_text(program(*body), budget=Budget(blocks=1000))
    assert [p.severity.value for p in result.problems] == ["error"]
    assert "its budget of" in result.problems[0].message
    assert "the rest of the program is not checked" in result.problems[0].message
    assert not result.ok


def test_a_time_budget_that_stops_a_run_is_an_error() -> None:
    moves = [f"L X+{n % 50} F100" for n in range(3000)]
    result = check_text(program(*moves), budget=Budget(seconds=0.0))
    assert [p.severity.value for p in result.problems] == ["error"]
    assert "its budget of 0 s of CPU ran out" in result.problems[0].message


def test_the_plain_line_path_draws_what_the_general_path_draws(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from opendnc.nccheck import klartext

    text = program(
        "L X+10 Y+5 R0 F200",
        "CYCL DEF 7.0 DATUM SHIFT",
        "CYCL DEF 7.1 X+3",
        "L X-4.5 Y+.5",
        "L  Z-2.25  F50",
        "L X+7. Y+8 Z+1 R0",
        "RND R1",
        "L X+20",
        "L X+20 Y+20 M5",
        "L X+0",
    )
    fast = check_text(text)
    monkeypatch.setattr(klartext, "_PLAIN_L", re.compile(r"(?!)"))  # never the fast path
    general = check_text(text)
    assert fast.moves == general.moves
    assert fast.problems == general.problems
    assert fast.end.position == general.end.position
    assert fast.feed_distance == general.feed_distance


def test_a_parameter_an_unsimulated_function_sets_is_not_read_before_set() -> None:
    result = check_text(program("FN 18: SYSREAD Q5 = ID990 NR1", "Q6 = Q5 + Q7"))
    assert [p.message.split(" is ")[0] for p in result.warnings] == ["FN 18", "Q7"]


def test_a_formula_continued_with_a_tilde_is_one_block() -> None:
    # "Q2 = ... + ( 5 * ~" then the rest on the next line, as the TNC's editor breaks it
    text = program("Q1 = 2", "Q2 = ( 1 + Q1 ) * ~\n    ( 4 - 1 )", "L X+Q2 R0 FMAX")
    result = check_text(text)
    assert result.errors == ()
    assert result.extents["X"] == (0.0, 9.0)


@pytest.mark.parametrize("head", ["FN 18: SYSREAD", "FN18: SYSREAD", "FN18:SYSREAD"])
def test_an_fn_head_is_read_in_any_spacing(head: str) -> None:
    # posts write "FN18: SYSREAD Q10 = ID50 NR2 IDX1" (no blank after FN, or after the colon)
    result = check_text(program(f"{head} Q10 = ID50 NR2 IDX1", "L X+Q10 R0 FMAX"))
    assert result.errors == ()
    assert [p.message for p in result.warnings] == ["FN 18 is not simulated by the dry run"]


@pytest.mark.parametrize("moves", [0, 1_000_000])
def test_a_corner_is_rounded_with_or_without_moves_kept(moves: int) -> None:
    # the command line keeps no moves: the corner still needs the line before it
    fits = check_text(
        program("L X+0 Y+0 Z-1 F100", "L X+20", "RND R2", "L Y+20"), budget=Budget(moves=moves)
    )
    assert fits.problems == ()
    # a 90-degree corner of R2 trims each line by 2 (R / tan 45): 18 + pi + 18
    assert fits.feed_distance == pytest.approx(1 + 18 + math.pi + 18)
    tight = check_text(
        program("L X+0 Y+0 Z-1 F100", "L X+1", "RND R2", "L Y+20"), budget=Budget(moves=moves)
    )
    assert [p.message for p in tight.errors] == ["RND 2 does not fit its corner"]


@pytest.mark.parametrize("block", ["FN18: SYSREAD Q5 = ID990 NR1", "FN 18:SYSREAD Q5 = ID990 NR1"])
def test_fn_with_or_without_a_blank_before_its_number(block: str) -> None:
    result = check_text(program(block, "Q6 = Q5 + 1"))
    assert result.errors == ()
    assert [p.message.split(" is ")[0] for p in result.warnings] == ["FN 18"]
