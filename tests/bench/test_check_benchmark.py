"""``benchmarks/check.py`` keeps working: its large cases at a small size, each in a child
process, run to the end and print CPU, peak RSS and blocks checked (the real sizes, 1M and
10M blocks, are too slow for the suite)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

BENCH = Path(__file__).resolve().parents[2] / "benchmarks" / "check.py"


def test_the_check_benchmark_runs_its_cases_to_the_end() -> None:
    done = subprocess.run(
        [sys.executable, str(BENCH), "--large", "3000", "--huge", "5000", "--runs", "0"],
        capture_output=True,
        text=True,
        timeout=240,
        check=True,
    )
    lines = done.stdout.splitlines()
    pattern = re.compile(
        r"^(gcode|klartext) +([\d,]+) blocks: checked ([\d,]+), to the end; CPU [\d.]+ s.*; "
        r"peak RSS \d+ MiB"
    )
    found = [pattern.match(line) for line in lines]
    assert all(found), lines
    cases = [(m.group(1), int(m.group(2).replace(",", ""))) for m in found if m]
    assert cases == [("gcode", 3000), ("klartext", 3000), ("gcode", 5000)]
    for m in found:
        assert m is not None
        # the generated programs have a few blocks of head and end beside the moves
        assert abs(int(m.group(3).replace(",", "")) - int(m.group(2).replace(",", ""))) < 10
