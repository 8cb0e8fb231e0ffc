"""``benchmarks/soak_serial_lsv2.py --smoke``: one round of serial LSV2 at 1e-4 bit errors, text
and binary both ways, and not one transfer reported success with wrong bytes."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

SOAK = Path(__file__).resolve().parents[2] / "benchmarks" / "soak_serial_lsv2.py"


def test_serial_soak_round_has_no_silent_corruption() -> None:
    proc = subprocess.run(
        [sys.executable, str(SOAK), "--smoke", "--json"],
        capture_output=True,
        text=True,
        timeout=240,
        check=False,
    )
    assert proc.stdout, proc.stderr
    result = json.loads(proc.stdout.splitlines()[-1])
    assert result["parity_failed"] > 0, "the line was clean"
    for case, tally in result["cases"].items():
        assert tally["cases"] == 1, case
        assert tally["silent"] == 0, (case, tally["notes"])
        assert tally["ok"] + tally["caught"] == 1, case
    assert proc.returncode == 0
