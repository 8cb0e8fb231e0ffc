"""The tool list's S and F are each tool's own: a Haas program sets them after M06, and the
values of the tool before must not carry over (the program page's tool table shows them)."""

from __future__ import annotations

from opendnc.nccheck import check_text


def test_each_tool_gets_the_first_s_and_f_after_its_change() -> None:
    result = check_text(
        "%\nO1\nG21 G90\n"
        "T1 M06\nG00 G54 X0. Y0. S1200 M03\nG43 H01 Z5.\nG01 Z-1. F800.\nX50.\n"
        "T3 M06\nG00 X0. Y0. S4000 M03\nG01 Z-2. F300.\nX20.\n"
        "T4 M06 S2500 F150.\nM03\nG01 Z-3.\n"
        "T5 M06\nG00 X5.\n"  # no S nor F of its own
        "M30\n%\n"
    )
    assert result.problems == ()
    facts = {t.tool: (t.speed, t.feed) for t in result.tools}
    assert facts == {
        "1": (1200.0, 800.0),
        "3": (4000.0, 300.0),
        "4": (2500.0, 150.0),
        "5": (None, None),
    }


def test_a_tool_called_again_keeps_its_first_values() -> None:
    result = check_text(
        "%\nO1\nT1 M06\nS1000 M03\nG01 X1. F100.\nT2 M06\nS2000\nF200.\n"
        "T1 M06\nS1500\nF150.\nM30\n%\n"
    )
    one, two = result.tools
    assert (one.tool, one.calls, one.speed, one.feed) == ("1", 2, 1000.0, 100.0)
    assert (two.tool, two.speed, two.feed) == ("2", 2000.0, 200.0)
