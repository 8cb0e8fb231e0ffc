"""The dry run reads a program as a stream: its memory does not grow with the program.

A program is generated to a file and checked with :func:`check_file` (as ``opendnc check``
does); tracemalloc measures the peak of what the check allocates. A run that kept a record
per block (the old list of parsed blocks, or every move) grows about linearly with the
program; a streamed run stays within what it must remember (labels, open loops, a few
pieces of re-readable blocks).
"""

from __future__ import annotations

import tracemalloc
from pathlib import Path

import pytest

from opendnc.nccheck import Budget, check_file, gcode, klartext, source


def _gcode(path: Path, blocks: int, tail: str = "") -> int:
    """A 3-D CAM-like program of about ``blocks`` blocks; returns the line of ``tail``."""
    with path.open("w", encoding="ascii") as out:
        out.write("%\nO01000\nG21 G90 T1 M06\nS5000 M03\nG01 Z-1. F800.\n")
        for i in range(blocks):
            feed = " F900." if i % 97 == 0 else ""
            out.write(f"X{i % 100 * 0.5:.3f} Y{i % 77 * 0.25:.3f} Z-{1 + i % 5 * 0.1:.3f}{feed}\n")
        out.write(f"{tail}\nM30\n%\n")
    return 5 + blocks + 1


def _peak(path: Path) -> int:
    tracemalloc.start()
    try:
        result = check_file(path, budget=Budget(seconds=None, moves=0))
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert result.ok, result.problems[:3]
    assert result.end.ended
    return peak


def test_memory_does_not_grow_with_a_gcode_program(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Small programs, read in pieces of 16 KiB with 4 pieces of blocks kept parsed (about
    # 1,000 blocks), so that both programs are well past what the run keeps: under tracemalloc
    # every allocation is traced, and the same check at the real sizes (a MiB, 16,000 blocks)
    # needs programs of 45,000 and 180,000 blocks, 40 CPU seconds.
    monkeypatch.setattr(source, "_PIECE", 1 << 14)
    monkeypatch.setattr(gcode, "_CACHED", 4)
    warm, small, large = tmp_path / "warm.nc", tmp_path / "small.nc", tmp_path / "large.nc"
    _gcode(warm, 500)  # the first run's one-off allocations (imports, compiled patterns)
    _gcode(small, 2_000)
    _gcode(large, 8_000)
    _peak(warm)
    peak_small, peak_large = _peak(small), _peak(large)
    # four times the blocks: a run that kept about 500 bytes a block would take 3 MB more
    # here; a streamed one holds the same pieces for both (measured: the same peak)
    assert peak_large < peak_small + 300_000, (peak_small, peak_large)


def test_a_loop_and_a_sub_program_behind_the_scan_are_read_again(tmp_path: Path) -> None:
    # the sub-program after M30 is reached by a forward scan; the loop jumps back over
    # more blocks than the pieces kept parsed, so they are read again from the file
    program = tmp_path / "loop.nc"
    body = "".join(f"X{i % 10}. Y{i % 7}.\n" for i in range(20_000))
    program.write_text(
        "%\nO01000\nG21 G90 T1 M06\nS5000 M03\nG01 Z-1. F800.\n#1 = 0\n"
        f"WHILE [#1 LT 3] DO1\n{body}#1 = #1 + 1\nEND1\nM97 P100\nM30\n"
        "N100 G01 X5. Y5.\n#2 = #1 * 2\nM99\n%\n",
        "ascii",
    )
    result = check_file(program, budget=Budget(seconds=None, moves=0))
    assert result.problems == ()
    assert result.end.ended
    assert result.end.variables[1] == 3.0
    assert result.end.variables[2] == 6.0
    # 4 blocks before the loop, the WHILE 4 times, 3 passes of the body with its count and
    # END1, the call, the sub-program's 3 blocks and M30: each pass of the loop counts
    assert result.blocks == 4 + 4 + 3 * (20_000 + 2) + 1 + 3 + 1


def test_the_last_block_error_of_a_large_gcode_program(tmp_path: Path) -> None:
    program = tmp_path / "last.nc"
    line = _gcode(program, 100_000, tail="G01 X1. #0=1")
    result = check_file(program, budget=Budget(seconds=None, moves=0))
    assert [(p.line, p.severity.value) for p in result.problems] == [(line, "error")]
    assert result.blocks == 3 + 100_000 + 1 + 1


def test_the_last_block_error_of_a_large_klartext_program(tmp_path: Path) -> None:
    program = tmp_path / "last.h"
    blocks = 100_000
    with program.open("w", encoding="ascii") as out:
        out.write("0 BEGIN PGM LAST MM\n1 TOOL CALL 1 Z S5000\n2 L Z+5 R0 FMAX M3\n")
        for n in range(3, blocks + 3):
            out.write(f"{n} L X{n % 100 * 0.5:+.3f} Y{n % 77 * 0.25:+.3f} Z-1 F800\n")
        n = blocks + 3
        out.write(f"{n} CALL LBL 99\n{n + 1} L Z+100 R0 FMAX M30\n{n + 2} END PGM LAST MM\n")
    result = check_file(program, budget=Budget(seconds=None, moves=0))
    assert [(p.line, p.block, p.severity.value) for p in result.problems] == [
        (blocks + 4, blocks + 3, "error")
    ]


def _klartext(path: Path, blocks: int) -> None:
    """A numbered Klartext 3-D program of about ``blocks`` straight moves."""
    with path.open("w", encoding="ascii") as out:
        out.write("0 BEGIN PGM BIG MM\n1 TOOL CALL 1 Z S5000\n2 L Z+5 R0 FMAX M3\n")
        for n in range(3, blocks + 3):
            feed = " F800" if n % 97 == 3 else ""
            x, y, z = n % 100 * 0.5, n % 77 * 0.25, 1 + n % 5 * 0.1
            out.write(f"{n} L X{x:+.3f} Y{y:+.3f} Z-{z:.3f}{feed}\n")
        n = blocks + 3
        out.write(f"{n} L Z+100 R0 FMAX M30\n{n + 1} END PGM BIG MM\n")


def test_memory_does_not_grow_with_a_klartext_program(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # as for G-code: pieces of 16 KiB read, 4 pieces of 256 blocks kept parsed
    monkeypatch.setattr(source, "_PIECE", 1 << 14)
    monkeypatch.setattr(klartext, "_CACHED", 4)
    warm, small, large = tmp_path / "warm.h", tmp_path / "small.h", tmp_path / "large.h"
    _klartext(warm, 500)
    _klartext(small, 2_000)
    _klartext(large, 8_000)
    _peak(warm)
    peak_small, peak_large = _peak(small), _peak(large)
    # a run that kept the blocks' texts (about 60 bytes and a list slot each) would take
    # 400 kB more for the 6,000 blocks more (measured: the old run 600 kB, this one 50 kB)
    assert peak_large < peak_small + 150_000, (peak_small, peak_large)


def test_a_klartext_label_after_the_call_and_a_repeat_read_again(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # two pieces kept: the repeat jumps back over more blocks than that, and the call
    # reads on to its label past the end of the main program
    monkeypatch.setattr(klartext, "_CACHED", 2)
    program = tmp_path / "labels.h"
    lines = ["BEGIN PGM LBLS MM", "TOOL CALL 1 Z S5000", "L Z+5 R0 FMAX M3", "LBL 1"]
    lines += [f"L X{i % 10:+d} Y{i % 7:+d} Z-1 F800" for i in range(2_000)]
    lines += ["CALL LBL 1 REP 2", "CALL LBL 20", "L Z+100 R0 FMAX M30"]
    lines += ["LBL 20", "Q5 = 7", "L X+3 Y+3", "LBL 0", "END PGM LBLS MM"]
    program.write_text("".join(f"{n} {line}\n" for n, line in enumerate(lines)), "ascii")
    result = check_file(program, budget=Budget(seconds=None, moves=0))
    assert result.problems == ()
    assert result.end.ended
    assert result.end.variables[5] == 7.0
    # 3 blocks, LBL 1, 3 passes of the 2,000 moves (a repeat goes on after its label), the
    # repeat's 3 runs, the call, the 3 blocks after LBL 20 (Q5, L, LBL 0) and the M30 block
    assert result.blocks == 3 + 1 + 3 * 2_000 + 3 + 1 + 3 + 1
