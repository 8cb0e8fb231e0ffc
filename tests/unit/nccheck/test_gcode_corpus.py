"""The G-code checker on a corpus written for these tests (tests/data/nccheck/corpus/gcode).

The clean programs are in the styles of common posts and hand-written programs (Fusion 360
for a Haas mill, Mastercam for a Fanuc mill, Renishaw probing macro calls, a Haas lathe, a
Fanuc lathe, a class program, a Fanuc mill and lathe with the machine builder's M codes, a
Haas tap whose cycle starts the spindle): each checks with no error, with its control
guessed and with its control named. Each defect file holds one defect class (or, for
``two_faults.nc``, a fault that used to end the run before a real one), checked with its
control guessed unless DEFECT_CONTROL names one; the test prints what was caught, missed and
falsely reported, then asserts none was missed and no error was false.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from opendnc.nccheck import Budget, CheckResult, MachineLimits, check_text

CORPUS = Path(__file__).resolve().parents[2] / "data" / "nccheck" / "corpus" / "gcode"
BUDGET = Budget(blocks=100_000)

# file -> the control it is written for
CLEAN = {
    "fusion_haas_mill.nc": "haas-mill",
    "mastercam_fanuc_mill.nc": "fanuc-mill",
    "renishaw_probing.nc": "haas-mill",
    "haas_lathe.nc": "haas-lathe",
    "fanuc_lathe.nc": "fanuc-lathe",
    "class_program.nc": "fanuc-mill",
    "fanuc_mill_builder_m_codes.nc": "fanuc-mill",
    "fanuc_lathe_builder_m_codes.nc": "fanuc-lathe",
    "haas_tap_spindle_from_cycle.nc": "haas-mill",
}

# file -> the errors it must give: (file line, words of the message)
DEFECTS: dict[str, list[tuple[int, str]]] = {
    "g83_without_q.nc": [(8, "G83 without a peck depth (Q)")],
    "comp_start_on_arc.nc": [(9, "cutter compensation start (G41) on an arc")],
    "comp_cancel_on_arc.nc": [(11, "cutter compensation cancel (G40) on an arc")],
    "comp_without_d.nc": [(9, "G41 without a cutter radius offset (D)")],
    "length_without_h.nc": [(7, "G43 without a tool length offset (H)")],
    "tap_spindle_stopped.nc": [(8, "a tap (G84) with the spindle stopped")],
    # a feed or speed has no sign: Fanuc P/S alarm 006 (docs/check.md#g-code)
    "negative_feed.nc": [(9, "F-250: a feed rate cannot be negative")],
    "negative_speed.nc": [(6, "S-4500: a spindle speed cannot be negative")],
    "feed_after_tool_change.nc": [(13, "below Z0 with the spindle stopped (M06 at line 10")],
    "feed_below_z0_stopped.nc": [(10, "below Z0 with the spindle stopped (M05 at line 9")],
    "m97_without_m99.nc": [(12, "O02009 ends without M99")],
    "alarm_reached.nc": [(5, "the program raises alarm 1012 (DIAMETER NOT SET)")],
    "missing_bracket.nc": [(4, "missing ']' to close the '[' at column 8")],
    "division_by_unset.nc": [(4, "division by zero: #105 is unset (null)")],
    "write_through_unset.nc": [(4, "writes #0 because #110 is unset (null)")],
    "overflowing_number.nc": [(4, "(321 digits) is out of range")],
    "comment_before_percent.nc": [(51, "below Z0 with the spindle stopped (M05 at line 50")],
    "two_faults.nc": [
        (6, "division by zero"),
        (11, "below Z0 with the spindle stopped (M05 at line 10"),
    ],
    "lathe_contour_missing.nc": [(10, "G71: no block N300 in O02016 (P100 Q300)")],
    "lathe_feed_stopped.nc": [(10, "below Z0 with the spindle stopped (M05 at line 9")],
}

# defect file -> the control it is checked with (else guessed): a fault of one control only
DEFECT_CONTROL = {
    # a Haas G84 starts the spindle itself, so only a Fanuc (without M29) stops here
    "tap_spindle_stopped.nc": "fanuc-mill",
}


def run(path: Path, dialect: str | None = None) -> CheckResult:
    machine = MachineLimits(dialect=dialect) if dialect else None
    return check_text(path.read_text("ascii"), name=path.name, machine=machine, budget=BUDGET)


@pytest.mark.parametrize("name", sorted(CLEAN))
def test_a_correct_program_checks_with_no_error(name: str) -> None:
    path = CORPUS / name
    for dialect in (None, CLEAN[name]):
        result = run(path, dialect)
        assert result.errors == (), (dialect, result.errors)
        assert result.end.ended
        assert result.tools
    assert result.dialect == CLEAN[name]


def test_the_defect_corpus_is_caught_without_false_errors(
    capsys: pytest.CaptureFixture[str],
) -> None:
    caught: list[str] = []
    missed: list[str] = []
    false: list[str] = []
    for name, expected in sorted(DEFECTS.items()):
        result = run(CORPUS / "defects" / name, DEFECT_CONTROL.get(name))
        errors = [(p.line, p.message) for p in result.errors]
        for line, words in expected:
            hit = any(at == line and words in message for at, message in errors)
            (caught if hit else missed).append(f"{name}:{line}: {words}")
        for line, message in errors:
            if not any(at == line and words in message for at, words in expected):
                false.append(f"{name}:{line}: {message}")
    with capsys.disabled():
        print(f"\nG-code defect corpus: {len(caught)} caught, {len(missed)} missed, "
              f"{len(false)} false errors")  # fmt: skip
        for label, items in (("missed", missed), ("false", false)):
            for item in items:
                print(f"  {label}: {item}")
    assert missed == []
    assert false == []
    assert len(caught) == sum(len(v) for v in DEFECTS.values())


def test_every_corpus_file_is_in_a_table() -> None:
    files = {p.name for p in CORPUS.glob("*.nc")}
    defects = {p.name for p in (CORPUS / "defects").glob("*.nc")}
    assert files == set(CLEAN)
    assert defects == set(DEFECTS)
