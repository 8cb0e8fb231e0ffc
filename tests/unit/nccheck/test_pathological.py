"""Inputs built to be slow or deep end quickly with problems, never with a crash or a hang."""

from __future__ import annotations

import time

import pytest

from opendnc.nccheck import Control, check_text

CASES = [
    # a long line of digits that almost matches the plain-word pattern (once exponential)
    (Control.HAAS, "%\nO1\n" + " ".join(["X" + "1" * 20] * 200) + " !\nM30\n%\n", 3),
    (Control.HAAS, "%\nO1\n#1 = " + "[" * 5000 + "1" + "]" * 5000 + "\nM30\n%\n", 3),
    (Control.HAAS, "%\nO1\n#1 = " + "#[" * 3000 + "1" + "]" * 3000 + "\nM30\n%\n", 3),
    (
        Control.HEIDENHAIN,
        "0 BEGIN PGM A MM\n1 Q1 = " + "(" * 5000 + "1" + ")" * 5000 + "\n2 END PGM A MM\n",
        2,
    ),
    (
        Control.HEIDENHAIN,
        "0 BEGIN PGM A MM\n1 FN 9: IF " + "+1 " * 20000 + "\n2 END PGM A MM\n",
        2,
    ),
]


@pytest.mark.parametrize(("control", "text", "line"), CASES)
def test_slow_or_deep_input_gives_a_problem(control: Control, text: str, line: int) -> None:
    started = time.thread_time()
    result = check_text(text, control=control)
    assert time.thread_time() - started < 2.0
    assert [p.line for p in result.errors] == [line]
    assert not result.errors[0].message.startswith("internal error")
