"""Heidenhain programs in the styles real posts and the TNC itself write, and one small file
per defect class (tests/data/nccheck/corpus/heidenhain/, all written for these tests).

Each correct program must check with no error (a check that flags a correct program blocks
its release); each defect file must give its problem on its line. The last test prints the
tally (caught / missed / false errors), as the issue asked.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from opendnc.nccheck import CheckResult, Severity, check_text

CORPUS = Path(__file__).resolve().parents[2] / "data" / "nccheck" / "corpus" / "heidenhain"
ERROR, WARNING = Severity.ERROR, Severity.WARNING

# the style each clean program stands for, and what it holds that was once a false error
CLEAN = {
    "fusion_bracket.h": "numbered ';' comment blocks, M13 with a move, RND/CHF, cycles 200, 207",
    "hypermill_plate.h": "cycles 32, 7, 232, 251, 253, 14, 20, 22, 24; Q206= AUTO; first move "
    "LP after a Z move; '/ 51 STOP' block skip",
    "tnc_saved_old_cycles.h": "old-style cycles 1.0-1.5 and 5.0-5.5 called by M99",
    "unnumbered_datum.h": "blocks without numbers after CYCL DEF 7.0",
    "iso_flange.i": "TNC ISO circle centre in its own block (N70 I+50 J+50 *)",
}

# file: [(line, severity, words in the message)]
DEFECTS = {
    "decimal_comma.h": [(6, ERROR, "a decimal comma (10,5)")],
    "positive_depth.h": [(4, ERROR, "cycle 200: depth Q201 is positive")],
    "rnd_first.h": [(4, ERROR, "RND needs a contour element before it")],
    "q_read_before_set.h": [(4, WARNING, "Q7 is read before the program sets it")],
    "cycl_call_label_missing.h": [(4, ERROR, "label CONTOUR is not defined")],
    "iso_no_end.i": [(9, ERROR, "no end block (N99999999 %NOEND)")],
    "two_errors.h": [(6, ERROR, "C without a circle centre"), (8, ERROR, "division by zero")],
}


def check(path: Path) -> CheckResult:
    return check_text(path.read_text("ascii"), name=path.name)


@pytest.mark.parametrize("name", CLEAN, ids=list(CLEAN))
def test_a_correct_program_has_no_error(name: str) -> None:
    result = check(CORPUS / name)
    assert result.errors == (), CLEAN[name]
    assert result.end.ended
    assert result.moves
    assert not [p for p in result.warnings if "spindle" in p.message]  # M3/M13 start first


@pytest.mark.parametrize("name", DEFECTS, ids=list(DEFECTS))
def test_each_defect_is_found_on_its_line(name: str) -> None:
    result = check(CORPUS / "defects" / name)
    found = [(p.line, p.severity) for p in result.problems]
    assert found == [(line, severity) for line, severity, _ in DEFECTS[name]]
    for problem, (_, _, words) in zip(result.problems, DEFECTS[name], strict=True):
        assert words in problem.message


def test_a_decimal_comma_is_never_read_as_a_shorter_number() -> None:
    result = check(CORPUS / "defects" / "decimal_comma.h")
    assert result.extents["X"] == (0.0, 10.5)


def test_the_corpus_tally(capsys: pytest.CaptureFixture[str]) -> None:
    caught = missed = false = 0
    for name in CLEAN:
        false += len(check(CORPUS / name).errors)
    for name, expected in DEFECTS.items():
        got = {(p.line, p.severity) for p in check(CORPUS / "defects" / name).problems}
        hits = sum((line, severity) in got for line, severity, _ in expected)
        caught += hits
        missed += len(expected) - hits
    with capsys.disabled():
        print(f"\nheidenhain corpus: {caught} caught, {missed} missed, {false} false errors")
    assert (missed, false) == (0, 0)
