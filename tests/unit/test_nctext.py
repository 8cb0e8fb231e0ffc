"""The NC text check (opendnc.nctext): what a program may hold, and where a problem is."""

from __future__ import annotations

from pathlib import Path

import pytest

from opendnc.errors import DncError, ProgramTextError
from opendnc.nctext import check_program, check_program_file, find_problem

GOOD = b"%\nO01000 (FIRST, lower case ok)\nG00 G90 X0. Y0.\nG01 X1.5 F36.\nM30\n%\n"


@pytest.mark.parametrize(
    "text",
    [
        GOOD,
        GOOD.replace(b"\n", b"\r\n"),
        GOOD.replace(b"\n", b"\r"),
        b"\n" + GOOD + b"\n" + b"\x1a" * 48,  # a Haas punch: leading LF, SUB padding
        b"\x12\x00\x00" + GOOD + b"\x14",  # DC codes mode: DC2 ... DC4, NUL leader
        b"\x7f\x00\r\n" + GOOD + b"\x00\x00\x7f",
        b"G01\tX1.\n#100=[#101+2]*3 (macro; [brackets]) ,R2. /M01\nDPRNT[X*#100[44]]\n",
        b"",
        b"\x00\x1a",
    ],
)
def test_programs_pass(text: bytes) -> None:
    assert find_problem(text) is None


@pytest.mark.parametrize(
    ("text", "line", "column", "offset", "byte", "reason"),
    [
        # the case: a newline turned into 0x02
        (b"%\nO1\nG01 X1.\x02G01 F;6.\n%\n", 3, 8, 12, 0x02, "a control character"),
        (b"%\nO1\nG01 X\xb1.\n%\n", 3, 6, 10, 0xB1, "not ASCII"),
        (b"%\nO1\nG01 X1. q5\n%\n", 3, 9, 13, ord("q"), "a lower-case letter outside a comment"),
        (b"%\nO1\nG01 X1.\x12\nM30\n%\n", 3, 8, 12, 0x12, "a tape code inside the program"),
        (b"%\nO1\nG01 X1.\x00\n\x00\nM30\n%\n", 3, 8, 12, 0x00, "a tape code inside the program"),
        (b"%\r\nO1\r\nG01 X1\x1b\r\n%\r\n", 3, 7, 13, 0x1B, "a control character"),
        (b"%\rO1\rG01 X1\x1b\r%\r", 3, 7, 11, 0x1B, "a control character"),
        # a comment ends at its line end: the next line's lower case is outside it
        (b"(open comment\ng01\n", 2, 1, 14, ord("g"), "a lower-case letter outside a comment"),
        (b"(bad \x02 in a comment)\n", 1, 6, 5, 0x02, "a control character"),
        (b"\x12\x02%\n", 1, 2, 1, 0x02, "a control character"),  # not a tape code: not leader
    ],
)
def test_problems_are_located(
    text: bytes, line: int, column: int, offset: int, byte: int, reason: str
) -> None:
    problem = find_problem(text)
    assert problem is not None
    assert (problem.line, problem.column, problem.offset, problem.byte, problem.reason) == (
        line,
        column,
        offset,
        byte,
        reason,
    )
    assert text[problem.offset] == byte


def test_error_names_block_and_offset() -> None:
    with pytest.raises(ProgramTextError) as caught:
        check_program(b"%\nO1\nG01 X1.\x02\n%\n", what="received program", action="not written")
    assert isinstance(caught.value, DncError)
    assert str(caught.value) == (
        "received program: byte 0x02 (a control character) at line 3, column 8, offset 12 "
        "(NC block 3) is not NC program text; not written"
    )
    assert caught.value.problem.line == 3


def test_file_check_reads_in_pieces(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import opendnc.nctext as nctext

    monkeypatch.setattr(nctext, "CHUNK", 7)
    path = tmp_path / "O1.nc"
    path.write_bytes(GOOD * 20 + b"G01 X1.\r\nG01 Xq\n" + GOOD)
    with pytest.raises(ProgramTextError) as caught:
        check_program_file(path)
    problem = caught.value.problem
    assert (problem.line, problem.column) == (20 * 6 + 2, 6)
    assert str(caught.value).startswith("O1.nc: byte 0x71")
    path.write_bytes(GOOD * 20 + b"\x1a" * 30)
    check_program_file(path)
