"""The checker on a corpus of programs written for these tests (tests/data/nccheck).

Clean programs for each control give no problem at all; each defect program gives exactly
its one problem, on the file line (and Klartext block) where a control would stop.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from opendnc.nccheck import (
    Budget,
    CheckResult,
    Control,
    MachineLimits,
    Severity,
    Units,
    check_text,
)

DATA = Path(__file__).resolve().parents[2] / "data" / "nccheck"
ERROR, WARNING = Severity.ERROR, Severity.WARNING


# a smaller block budget than the default keeps the endless-loop cases quick
BUDGET = Budget(blocks=100_000)


def run(name: str, **kwargs: object) -> CheckResult:
    text = (DATA / name).read_text("ascii")
    return check_text(text, name=name, budget=BUDGET, **kwargs)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("name", "control", "units"),
    [
        ("clean_haas.nc", Control.HAAS, Units.MM),
        ("clean_fanuc_macro.nc", Control.HAAS, Units.INCH),
        ("clean_iso.i", Control.ISO, Units.MM),
        ("clean_klartext.h", Control.HEIDENHAIN, Units.MM),
    ],
)
def test_clean_programs_have_no_problem(name: str, control: Control, units: Units) -> None:
    result = run(name)
    assert result.problems == ()
    assert result.control is control
    assert result.units is units
    assert result.end.ended
    assert result.moves
    assert result.feed_distance > 0


# file, line, block (Klartext), severity, words the message must hold
DEFECTS = [
    ("unknown_g.nc", 7, None, ERROR, "G200 is not a G code"),
    ("unknown_m.nc", 6, None, ERROR, "M45 is not a M code"),
    ("word_without_value.nc", 7, None, ERROR, "address X has no value"),
    ("goto_missing.nc", 4, None, ERROR, "no block N40"),
    ("division_by_zero.nc", 5, None, ERROR, "division by zero"),
    ("read_only_write.nc", 4, None, ERROR, "#3020 is read-only"),
    ("no_program_end.nc", 6, None, ERROR, "no program end"),
    ("endless_loop.nc", 6, None, ERROR, "endless loop"),
    ("arc_radius_mismatch.nc", 8, None, ERROR, "not on its circle"),
    ("arc_radius_too_small.nc", 8, None, ERROR, "too small for a chord of 30"),
    ("call_not_in_library.nc", 5, None, WARNING, "O04321, which is not in the library"),
    ("feed_without_f.nc", 7, None, ERROR, "no feed rate"),
    ("cycle_without_depth.nc", 7, None, ERROR, "without a depth (Z)"),
    ("while_without_end.nc", 4, None, ERROR, "WHILE ... DO1 without END1"),
    ("iso_unknown_g.i", 4, None, ERROR, "G65 is not a G code of the Heidenhain ISO control"),
    ("lower_case_word.nc", 6, None, ERROR, "byte 0x79 (a lower-case letter outside a comment)"),
    ("kt_cr_radius_too_small.h", 8, 7, ERROR, "too small for a chord of 60"),
    ("kt_missing_label.h", 8, 7, ERROR, "label 7 is not defined"),
    ("kt_end_pgm_mismatch.h", 9, 8, ERROR, "END PGM OTHER does not match BEGIN PGM TEST"),
    ("kt_call_pgm_not_in_library.h", 8, 7, WARNING, "CALL PGM SUB1.H: not in the library"),
    ("kt_division_by_zero.h", 9, 8, ERROR, "division by zero"),
    ("kt_endless_loop.h", 10, 9, ERROR, "endless loop: the jump back at line 10"),
    ("kt_circle_without_cc.h", 8, 7, ERROR, "without a circle centre (CC)"),
    ("kt_cycl_call_without_def.h", 9, 8, ERROR, "CYCL CALL without a cycle defined"),
    ("kt_arc_end_off_circle.h", 9, 8, ERROR, "start radius 20.0000, end radius 25.0000"),
    ("kt_no_end_pgm.h", 8, 7, ERROR, "no END PGM"),
    ("kt_unknown_m.h", 4, 3, ERROR, "M77 is not an M function"),
    ("kt_unknown_block_in_unused_label.h", 6, 5, ERROR, "unknown block 'LX+10'"),
]


# defect -> the control it is checked with (else guessed): M45 is no Haas M code, but a
# guessed control takes every M code, as a Fanuc does (docs/check.md#dialects)
DEFECT_DIALECT = {"unknown_m.nc": "haas-mill"}


@pytest.mark.parametrize(
    ("name", "line", "block", "severity", "words"), DEFECTS, ids=[d[0] for d in DEFECTS]
)
def test_each_defect_is_found_on_its_line(
    name: str, line: int, block: int | None, severity: Severity, words: str
) -> None:
    dialect = DEFECT_DIALECT.get(name)
    result = run(name, machine=MachineLimits(dialect=dialect) if dialect else None)
    assert [(p.line, p.block, p.severity) for p in result.problems] == [(line, block, severity)]
    assert words in result.problems[0].message
    assert result.ok is (severity is WARNING)


def test_a_called_program_from_the_library_is_run() -> None:
    sub = "%\nO04321\n#500 = 7\nM99\n%\n"
    result = run("call_not_in_library.nc", library={"O04321": sub}.get)
    assert result.problems == ()
    assert result.end.variables[500] == 7


def test_a_haas_program_for_a_tnc_is_an_error() -> None:
    tnc = MachineLimits(name="mill-1", family="heidenhain")
    result = run("clean_haas.nc", machine=tnc)
    assert [(p.line, p.severity) for p in result.problems] == [(1, ERROR)]
    assert "cannot run on mill-1 (heidenhain control)" in result.problems[0].message


def test_protected_program_numbers_on_a_haas() -> None:
    haas = MachineLimits(name="vf2", family="haas", protected=((8000, 9999),))
    result = run("protected_number.nc", machine=haas)
    assert [(p.line, p.severity) for p in result.problems] == [(2, ERROR)]
    assert "O09010 is a protected program number" in result.problems[0].message
    assert run("protected_number.nc").problems == ()


def test_travel_with_the_configured_work_offset() -> None:
    vf2 = MachineLimits(
        name="vf2",
        family="haas",
        travel={"X": (-30.0, 0.0), "Y": (-16.0, 0.0), "Z": (-20.0, 0.0)},
        work_offsets={"G54": {"X": -25.0, "Y": -8.0, "Z": -12.0}},
    )
    result = run("travel_overrun.nc", machine=vf2)
    assert [(p.line, p.severity) for p in result.problems] == [(8, ERROR)]
    assert "X goes to -35 in machine coordinates, below the X travel's minimum -30" in (
        result.problems[0].message
    )
    # without the work offset only G53 / G28 moves could be checked: nothing to say here
    unknown = MachineLimits(name="vf2", family="haas", travel=vf2.travel)
    assert run("travel_overrun.nc", machine=unknown).problems == ()


def test_tools_missing_from_the_machine() -> None:
    vf2 = MachineLimits(name="vf2", family="haas", tools=frozenset({"1"}))
    result = run("clean_haas.nc", machine=vf2)
    assert [(p.line, p.severity) for p in result.problems] == [(25, ERROR)]
    assert "tool T2 is not in the tool table of vf2" in result.problems[0].message
