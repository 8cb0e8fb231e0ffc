"""Property tests: the checker only ever returns problems (never raises, never hangs)."""

from __future__ import annotations

import json
import math
import time

from hypothesis import example, given, settings
from hypothesis import strategies as st

from opendnc.nccheck import Budget, CheckResult, Control, MachineLimits, check_text

BUDGET = Budget(blocks=20_000, seconds=1.0)
LIMITS = MachineLimits(
    name="m",
    family="haas",
    travel={"X": (-30.0, 0.0), "Z": (-20.0, 0.0)},
    work_offsets={"G54": {"X": -10.0, "Z": -5.0}},
    tools=frozenset({"1", "2"}),
    protected=((8000, 9999),),
)

gcode_lines = st.sampled_from(
    [
        "%", "O1000", "O09010", "G00 X1. Y2. Z3.", "G01 X-1. F10.", "G02 X1. Y1. I1. J0.",
        "G03 X0 Y0 R-0.5", "G03 X5 R1.", "G02 X1", "G91", "G90", "G20", "G21", "G17",
        "G18", "G19", "G54", "G154 P3", "G154 P0", "G28 G91 Z0.", "G53 Z-1.", "T1 M06",
        "T#1 M06", "M03 S1000", "M05", "M30", "M99", "M97 P10", "M98 P1000 L2",
        "G65 P1000 A1. B2.", "N10 #1 = #1 + 1", "GOTO 10", "IF [#1 LT 5] GOTO 10",
        "WHILE [#1 LT 3] DO1", "END1", "#3000 = 1 (STOP)", "#3020 = 1", "#[#1] = 5",
        "#1 = 1/0", "#1 = SQRT[-1]", "G81 Z-1. R0.1 F5.", "X1. Y1.", "G80", "G98", "G99",
        "G04 P1.", "G10 L2 P1 X1.", "G52 X1.", "G92 X0", "G12", "G65", "M97", "X", "G",
        "DPRNT[X#5041[44]]", "POPEN", "(COMMENT", "/G00 X1.", "G1X1.Y2.Z3.F4.",
        "#1 = #1 + [", "G95 F0.1", "G93 F2.", "G73 Z-2. R1. Q0.5 L3",
        # Fanuc and lathe words (dialects), overflowing numbers, unset variables
        "G71 U2. R0.5", "G71 P10 Q20 U0.5 W0.1 F0.3", "G70 P10 Q20", "G70 P20 Q10",
        "N20 X5.", "G96 S200", "G97 S500", "G50 S3000", "G50 X10. Z1.", "T0101",
        "G01 U-2. W-5. F0.2", "G54.1 P2", "G54.1 P400", "M29 S500", "G84 Z-5. R1. F1.",
        "G41 D1 X1.", "G42 G02 X1. R1.", "G40 G02 X1. R1.", "G43 Z1.", "#3001 = 0",
        "S" + "9" * 320, "F1" + "0" * 40 + ".5", "#1 = 1 / #7", "#[#9] = 2",
        "G76 X1. Z-1. K0.1 D0.1 F1.", "G90 X10. Z-5. F0.2", "G83 Z-5. R1.", "G32 W-10. F1.5",
        "IF [#1 GT [2 GOTO 10", "#3000 = 2000",
    ]
)  # fmt: skip
klartext_lines = st.sampled_from(
    [
        "0 BEGIN PGM A MM", "END PGM A MM", "END PGM B INCH", "BLK FORM 0.1 Z X+0 Y+0 Z-20",
        "BLK FORM 0.2 X+100 Y+100 Z+0", "BLK FORM 0.2 X-1", "TOOL CALL 1 Z S3000 F200",
        'TOOL CALL "MILL" Z', "TOOL CALL Q1 Z", "L X+10 Y+10 R0 FMAX M3", "L Z-5 F100",
        "L IX+1 RL", "L X+Q1 F AUTO", "CC X+0 Y+0", "CC", "C X+10 Y+0 DR+", "C X+1 DR-",
        "CR X+5 Y+5 R+2 DR-", "CR X+5 R-50 DR+", "CT X+20 Y+3", "RND R2", "RND R-1",
        "CHF 1", "LP PR+10 PA+45 R0", "CP IPA+720 IZ-2 DR+ F50", "CP PA+90 DR-", "LBL 1",
        "LBL 0", 'LBL "X"', "CALL LBL 1 REP 3", "CALL LBL 9", 'CALL LBL "X"',
        "CALL PGM SUB.H", "FN 0: Q1 = +5", "FN 4: Q2 = +1 DIV +Q3",
        "FN 9: IF +Q1 EQU +5 GOTO LBL 1",
        "Q5 = SIN(Q1) ^ 2 + SQRT 4", "Q6 = (1 + ", "FN 14: ERROR = 1",
        "CYCL DEF 200 DRILLING", "Q200=2", "Q201=-5", "Q206=100", "Q203=+0", "Q204=20",
        "CYCL CALL", "CYCL CALL PAT", "PATTERN DEF POS1 (X+1 Y+2 Z+0)", "CYCL DEF 7.0 DATUM",
        "CYCL DEF 7.1 X+5", "L X+0 R0 FMAX M99", "M89", "STOP", "STOP M5", "M30", "FN 18: SYSREAD",
        "PLANE SPATIAL", "~", "; comment", "* - part",
        # round 2: forms that were false errors or misses
        "L X+10,5 Y+0", "RND R0,5", "/ 12 STOP", "13 /L X+1", "3 ; T1 D=12", "CYCL DEF 1.0 X",
        "CYCL DEF 1.1 SET UP 2", "CYCL DEF 251 POCKET", "CYCL DEF 14.0 CONTOUR",
        "Q206= AUTO", "Q204=PREDEF", "Q201=+5", "LP PR+5 PA+0", "LP IPA+10", "M13",
        "L X+1 Y+1 F100 M13", 'CALL PGM "A,1"', "FN 18: SYSREAD Q5 = ID990 NR1",
        "QL3 = QL4 + 1", "L X+1 Y+" + "9" * 309, "9" * 309 + " L X+1",
    ]
)  # fmt: skip


def numbered(lines: list[str]) -> str:
    return "\n".join(f"{i} {line}" if i % 5 else line for i, line in enumerate(lines))


def assert_well_formed(result: CheckResult, text: str) -> None:
    assert isinstance(result, CheckResult)
    lines = text.count("\n") + text.count("\r") + 2
    for problem in result.problems:
        assert 1 <= problem.line <= lines
        assert problem.message
        assert problem.message == problem.message.strip()
        assert not problem.message.startswith("internal error")
    json.loads(result.to_json())


def checked(text: str, control: Control | None, machine: MachineLimits | None) -> CheckResult:
    started = time.thread_time()
    result = check_text(text, control=control, machine=machine, budget=BUDGET)
    # the budget is 1 s of this thread's CPU time (wall time on a shared machine says little);
    # parsing and building the result come on top of it
    assert time.thread_time() - started < 3.0
    return result


controls = st.sampled_from([None, Control.HAAS, Control.HEIDENHAIN, Control.ISO])
machines = st.sampled_from(
    [None, LIMITS, MachineLimits(dialect="fanuc-lathe"), MachineLimits(dialect="haas-mill")]
)


@settings(max_examples=150, deadline=None)
@given(st.text(max_size=300), controls, machines)
def test_any_text_gives_a_result(text: str, control: Control | None, machine: object) -> None:
    assert isinstance(machine, MachineLimits | None)
    assert_well_formed(checked(text, control, machine), text)


@settings(max_examples=150, deadline=None)
@given(st.lists(gcode_lines, max_size=40), controls, machines)
def test_gcode_soup_gives_a_result(
    lines: list[str], control: Control | None, machine: object
) -> None:
    assert isinstance(machine, MachineLimits | None)
    text = "\n".join(lines)
    assert_well_formed(checked(text, control, machine), text)


@settings(max_examples=150, deadline=None)
@given(st.lists(klartext_lines, max_size=40), machines)
def test_klartext_soup_gives_a_result(lines: list[str], machine: object) -> None:
    assert isinstance(machine, MachineLimits | None)
    text = numbered(["BEGIN PGM A MM", *lines])
    assert_well_formed(checked(text, Control.HEIDENHAIN, machine), text)


formula_tokens = st.sampled_from(
    [
        "Q1", "QL2", "QR3", "-", "+", "*", "/", "^", "(", ")", "0", "2", "-8", "0.5", "400",
        "SIN", "SQRT", "LN", "LOG", "ASIN", "EXP", "DIV", "LEN", "PI", "ABS", "FRAC", "1E308",
    ]
)  # fmt: skip


@settings(max_examples=300, deadline=None)
@given(st.lists(formula_tokens, min_size=1, max_size=12))
@example(["Q1", "^", "0.5"])  # a negative base to a fraction once gave a complex number
@example(["0", "^", "-", "2"])
def test_q_formulas_give_a_value_or_a_problem(tokens: list[str]) -> None:
    formula = " ".join(tokens)
    text = f"0 BEGIN PGM A MM\n1 Q1 = -8\n2 Q9 = {formula}\n3 END PGM A MM\n"
    result = checked(text, Control.HEIDENHAIN, None)
    assert_well_formed(result, text)
    if 9 in result.end.variables:
        assert math.isfinite(result.end.variables[9])
    else:
        assert [p.line for p in result.errors] == [3]


plain_words = st.builds(
    lambda letter, digits: letter + digits,
    st.sampled_from("GXYZF"),
    st.from_regex(r"[0-9]{1,25}(\.[0-9]{0,5})?", fullmatch=True),
)


@settings(max_examples=100, deadline=None)
@given(st.lists(plain_words, min_size=1, max_size=80), st.sampled_from(["", " !", "(", "#", "Q"]))
def test_long_plain_lines_stay_fast(words: list[str], tail: str) -> None:
    line = " ".join(words) + tail
    text = f"%\nO1\n{line}\nM30\n%\n"
    assert_well_formed(checked(text, Control.HAAS, None), text)


_bracketed = st.recursive(
    st.sampled_from(["1", "#1", "2.5", "SIN[30.]"]),
    lambda inner: st.one_of(
        st.builds(lambda a, b: f"[{a} + {b}]", inner, inner),
        st.builds(lambda a: f"ABS[{a}]", inner),
    ),
    max_leaves=6,
)


@settings(max_examples=60, deadline=None)
@given(_bracketed, st.data(), st.sampled_from(["", "N10 ", "/ ", "(NOTE) "]))
def test_a_missing_bracket_names_the_column_of_its_opening(
    expression: str, data: st.DataObject, prefix: str
) -> None:
    from opendnc.errors import InputError
    from opendnc.gcode.program import parse_block

    closing = [i for i, c in enumerate(expression) if c == "]"]
    if not closing:
        return
    cut = data.draw(st.sampled_from(closing))
    line = f"{prefix}#100 = {expression[:cut]}{expression[cut + 1 :]}"
    try:
        parse_block(line)
    except InputError as exc:
        message = str(exc)
        assert "missing ']' to close the '[' at column " in message
        column = int(message.split(" at column ")[1].split()[0])
        assert line[column - 1] == "["
    else:
        raise AssertionError(f"{line!r} parsed")


_numbers = st.from_regex(r"[+-]?([0-9]{1,4}(\.[0-9]{0,4})?|\.[0-9]{1,4})", fullmatch=True)
_words = st.builds(lambda letter, number: letter + number, st.sampled_from("NGMXYZFR"), _numbers)


_gaps = st.sampled_from(["", " ", "  "])
# X, Y, Z and F once each, in that order, as a CAM post writes a surface (points or none)
_moves = st.lists(
    st.tuples(st.builds(lambda k, n: k + n, st.sampled_from("XYZF"), _numbers), _gaps),
    max_size=4,
    unique_by=lambda word: word[0][0],
).map(lambda words: sorted(words, key=lambda word: "XYZF".index(word[0][0])))


@settings(max_examples=400, deadline=None)
@given(
    st.sampled_from(["", " ", "\t", "N12 ", "N7"]),
    st.one_of(st.lists(st.tuples(_words, _gaps), max_size=6), _moves),
    st.sampled_from(["", ";", " ;", "\r"]),
)
def test_plain_words_read_as_the_block_parser_reads_them(
    head: str, words: list[tuple[str, str]], tail: str
) -> None:
    """The dry run's quick readings of a plain line (parse_plain; parse_axes for a line of
    X/Y/Z/F words) give the N number and the words, each an int or a float as written,
    that the block parser gives the same line."""
    from opendnc.gcode.program import Num, Words, parse_axes, parse_block, parse_plain

    line = head + "".join(word + gap for word, gap in words) + tail
    plain = parse_plain(line)
    axes = parse_axes(line)
    if plain is None:
        assert axes is None  # a line of X/Y/Z/F words is a plain line
        return
    number, found = plain
    block = parse_block(line)
    assert isinstance(block.statement, Words)
    assert all(type(expr) is Num for _, expr in block.statement.words)
    expected = [(letter, expr.value, type(expr.value)) for letter, expr in block.statement.words]
    assert [(letter, value, type(value)) for letter, value in found] == expected
    assert number == block.number
    if axes is not None:
        assert axes[0] == block.number
        assert [(letter, value, type(value)) for letter, value in axes[1].items()] == expected


# lines of plain moves, the dry runs' quick paths, and their near misses
plain_gcode_lines = st.sampled_from(
    [
        "X1.5 Y2.5 Z-1.", "N20 X1. Y2.", "X.5 F300.", "Z-2.25", "Y3. Z1. F20.", "X1 Y2",
        "x1. y2.", "X1. X2.", "N5 Z1.;", "  X1.0 Y-2.0  ", "F100.", "Y1. X2.", "G01 X1. Y1.",
    ]
)  # fmt: skip
plain_klartext_lines = st.sampled_from(
    [
        "L X+1 Y+2 Z-1", "L X+1.5 Y-2.25 F500", "L Z-1 R0 F300", "L Y+3 X+1", "l x+1 y+2",
        "L X+1 ; note", "L X+1 Y+2 ~", "L X+1,5 Y+2", "L X+1 Y+2 Z+3 R0 F100", "L  X+1",
        "L X+1 X+2", "L X+2 Y+2 FMAX", "L X+5 Y+5 F200 M3", "L X+1 R0 F" + "9" * 16, "~",
        "Y+4 ~",
    ]
)  # fmt: skip


@settings(max_examples=150, deadline=None)
@given(st.lists(st.one_of(gcode_lines, plain_gcode_lines), max_size=40), machines)
def test_gcode_plain_moves_read_quickly_check_as_read_word_by_word(
    lines: list[str], machine: MachineLimits | None
) -> None:
    """A block of X/Y/Z/F words read by letter (parse_axes) runs as the same block read
    word by word does: the whole result is the same."""
    from unittest import mock

    from opendnc.nccheck import gcode

    text = "%\nO1000\nS1000 M03\n" + "\n".join(lines) + "\nM30\n%\n"
    quick = check_text(text, control=Control.HAAS, machine=machine, budget=BUDGET)
    with mock.patch.object(gcode, "parse_axes", return_value=None):
        slow = check_text(text, control=Control.HAAS, machine=machine, budget=BUDGET)
    assert quick == slow


@settings(max_examples=300, deadline=None)
@given(st.lists(st.one_of(klartext_lines, plain_klartext_lines), max_size=40), machines)
@example(["STOP", "L X+10 Y+10", "~", "L X+1.5 Y-2.25 F500"], None)  # a "~" line joins the next one
def test_klartext_plain_moves_read_quickly_check_as_read_step_by_step(
    lines: list[str], machine: MachineLimits | None
) -> None:
    """A plain ``L`` line taken apart as it is read runs as the same line read step by step
    (comment, case, "~", number, then its text matched when it runs): the same result."""
    import re
    from unittest import mock

    from opendnc.nccheck import klartext

    text = "0 BEGIN PGM A MM\n" + numbered(lines) + f"\n{len(lines) + 1} END PGM A MM\n"
    quick = check_text(text, control=Control.HEIDENHAIN, machine=machine, budget=BUDGET)
    with mock.patch.object(klartext, "_PLAIN_LINE", re.compile(r"(?!)")):  # never matches
        slow = check_text(text, control=Control.HEIDENHAIN, machine=machine, budget=BUDGET)
    assert quick == slow
