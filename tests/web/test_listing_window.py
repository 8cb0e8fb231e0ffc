"""The program text's server-side window (opendnc.server.web.listing), worked out by hand."""

from __future__ import annotations

from tests.peers import require_module

require_module("jinja2")
require_module("pygments")

from opendnc.server.web.listing import BEFORE, WINDOW, window  # noqa: E402


def numbered(lines: int) -> str:
    return "".join(f"G01 X{i}.\n" for i in range(1, lines + 1))


def test_a_short_text_is_one_window() -> None:
    shown = window("%\nO1\nM30\n%\n", name="O1.nc", size=14)
    assert (shown.first, shown.last, shown.total, shown.target) == (1, 4, 4, None)
    assert (shown.previous, shown.next) == (None, None)
    assert shown.dialect == "gcode"
    assert shown.scripted


def test_the_window_starts_a_little_above_the_line_asked_for() -> None:
    shown = window(numbered(1000), name="P.nc", size=9000, line=500)
    first = 500 - BEFORE
    assert (shown.first, shown.last, shown.target) == (first, first + WINDOW - 1, 500)
    assert ">500<" in str(shown.lines[BEFORE])  # X500. as highlighted (X and 500 apart)
    # the links ask for the line that starts the window before and after
    assert shown.previous == first - WINDOW + BEFORE
    assert shown.next == first + WINDOW + BEFORE


def test_a_line_beyond_the_end_shows_the_end() -> None:
    shown = window(numbered(30), name="P.nc", size=300, line=10**6)
    assert (shown.target, shown.first, shown.last, shown.next) == (30, 10, 30, None)


def test_an_empty_last_line_still_counts_when_it_is_a_line() -> None:
    # "a\n\n" is two lines: "a" and an empty one (the final newline ends the second)
    shown = window("a\n\n", name="P.nc", size=3)
    assert shown.total == 2
    assert len(shown.lines) == 2


def test_an_empty_text_has_no_line() -> None:
    shown = window("", name="P.nc", size=0, line=5)
    assert (shown.total, shown.lines, shown.target) == (0, [], None)


def test_klartext_is_named_for_the_script_and_large_texts_are_not_fetched() -> None:
    assert window("0 BEGIN PGM A MM\n1 END PGM A MM\n", name="A.H", size=30).dialect == "klartext"
    assert not window("G0 X1\n", name="P.nc", size=64 * 1024 * 1024).scripted


def test_the_marks_of_a_line_keep_its_worst_problem_and_every_message() -> None:
    from opendnc.server.web.listing import Mark, marks

    found = marks(
        [
            {"line": 4, "severity": "warning", "message": "no coolant"},
            {"line": 4, "severity": "error", "message": "G999 unknown"},
            {"line": 9, "severity": "warning", "message": "feed 0"},
        ]
    )
    assert found == {
        4: Mark("error", "warning: no coolant\nerror: G999 unknown"),
        9: Mark("warning", "warning: feed 0"),
    }
