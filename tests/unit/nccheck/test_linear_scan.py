"""Shapes that once made the control guess and the title parser backtrack for minutes.

A file of 4,096 blank lines froze the server for 78-105 s (a MULTILINE ``^\\s*\\d*\\s*``
pattern spanned lines); text with CR-only line ends, one huge line and very long numbers
are the other shapes a regex can trip on. Each must be answered quickly (the bound is
generous; precise timing belongs in benchmarks/check.py).
"""

from __future__ import annotations

import time

import pytest

from opendnc.nccheck import Budget, Control, check_text, guess_control
from opendnc.server.library.titles import HEAD, title_of

BOUND_S = 1.0

SHAPES = {
    "blank lines": "\n" * 4096 + "X",
    "blank lines with spaces": " \n\t" * 1400 + "1",
    "CR-only line ends": "\r" * 4096 + "0 BEGIN PGM A MM\r1 END PGM A MM\r",
    "CR-only blanks": " \r" * 4096,
    "one 50 MB line": "1 " + " " * 50_000_000,
    "309-digit numbers": ("9" * 309 + " ") * 20 + "\n" + "N" + "9" * 309 + " X" + "9" * 309,
    "digits then blanks": ("1" * 300 + " " * 300) * 7,
}


def _timed(call: object, *args: object, **kwargs: object) -> tuple[object, float]:
    started = time.thread_time()
    result = call(*args, **kwargs)  # type: ignore[operator]
    return result, time.thread_time() - started


@pytest.mark.parametrize("shape", SHAPES, ids=list(SHAPES))
def test_the_control_guess_is_quick(shape: str) -> None:
    _, spent = _timed(guess_control, SHAPES[shape])
    assert spent < BOUND_S


@pytest.mark.parametrize("shape", SHAPES, ids=list(SHAPES))
def test_the_title_is_quick(shape: str) -> None:
    _, spent = _timed(title_of, SHAPES[shape][:HEAD].encode("latin-1"))
    assert spent < BOUND_S


@pytest.mark.parametrize("shape", SHAPES, ids=list(SHAPES))
@pytest.mark.parametrize("control", [Control.HEIDENHAIN, None])
def test_check_is_quick_and_never_crashes(shape: str, control: Control | None) -> None:
    text = SHAPES[shape]
    if control is None:
        # the guess picks the G-code run here, whose whole-file byte checks make a 50 MB
        # line cost seconds (linear, not a hang): 5 MB of it keeps the suite cheap
        text = text[:5_000_000]
    result, spent = _timed(check_text, text, control=control, budget=Budget(seconds=1))
    assert spent < 3 * BOUND_S  # the dry run's own budget is 1 s of CPU here
    assert not any(p.message.startswith("internal error") for p in result.problems)  # type: ignore[attr-defined]


def test_cr_only_line_ends_are_lines() -> None:
    text = "0 BEGIN PGM A MM\r1 ; BRACKET OP1\r2 END PGM A MM\r"
    assert guess_control("\r" * 100 + text) is Control.HEIDENHAIN
    assert title_of(text.encode("latin-1")) == "BRACKET OP1"
    assert guess_control("%\rO1000\rG0 X1.\rM30\r%") is Control.HAAS
    assert guess_control("\r\r  %PART G71 *\rN10 G00 X+0 *\r") is Control.ISO


# One long line of user text that a regex searched from every position (or split a blank run
# every way) in quadratic time: 20 kB of the decimal-comma shape took 11.7 s before. Each
# 200 kB line must be checked well inside the bound.
_LONG = 200_000


def _klartext(block: str) -> str:
    return f"0 BEGIN PGM A MM\n1 {block}\n2 END PGM A MM\n"


LONG_LINES = {
    "decimal comma after a digit run": (
        _klartext("L X" + "1" * _LONG + ",X Y1,5"),
        Control.HEIDENHAIN,
        "a decimal comma (1,5)",
    ),
    "axis word, blanks, no value": (_klartext("L X" + " " * _LONG + "!"), Control.HEIDENHAIN, ""),
    "cycle parameter, blanks around =": (
        _klartext("CYCL DEF 200 Q200" + " " * _LONG + "=" + " " * _LONG + "!"),
        Control.HEIDENHAIN,
        "",
    ),
    "pattern points never closed": (
        _klartext("PATTERN DEF " + "POS1 (" * (_LONG // 6)),
        Control.HEIDENHAIN,
        "",
    ),
    "alarm comment never closed": (
        "%\nO1\n#3000=1" + "(" * _LONG + "\nM30\n%\n",
        Control.HAAS,
        "raises alarm 1001 (PROGRAMMABLE ALARM)",
    ),
}


@pytest.mark.parametrize("shape", LONG_LINES, ids=list(LONG_LINES))
def test_a_long_line_is_scanned_in_linear_time(shape: str) -> None:
    text, control, words = LONG_LINES[shape]
    result, spent = _timed(check_text, text, control=control, budget=Budget(seconds=30))
    assert spent < BOUND_S
    assert not words or any(words in p.message for p in result.problems)  # type: ignore[attr-defined]
