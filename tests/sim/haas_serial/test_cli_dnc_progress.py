"""`opendnc haas dnc --from-line` shows progress in the bytes it sends, not the file's size."""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path

from typer.testing import CliRunner

from opendnc.cli.main import app
from tests.sim.haas_serial.conftest import Bench
from tests.sim.haas_serial.test_dnc_serial import dnc_options


def test_restart_progress_counts_what_is_sent(
    bench_factory: Callable[..., Bench], tmp_path: Path
) -> None:
    bench = bench_factory(dnc_options())
    program = tmp_path / "p.nc"
    moves = "".join(f"G01 X{i}. Y{i % 7}.5 F20.\n" for i in range(60))
    program.write_text(f"%\nO03100 (PROGRESS)\nG20\nT4 M06\nG54\nS1500 M03\n{moves}M30\n%\n")
    args = ["haas", "dnc", str(program), "--port", bench.pc_path, "--baud", "115200"]
    result = CliRunner().invoke(app, [*args, "--unsafe", "--from-line", "50"])
    assert result.exit_code == 0, result.output
    sent = int(re.search(r"(\d+) bytes, \d+ blocks", result.output).group(1))  # type: ignore[union-attr]
    bar = re.search(r"(\d+)/(\d+) bytes", result.output)
    assert bar is not None, result.output
    assert sent < program.stat().st_size / 2  # the restart skips most of the file
    assert (int(bar.group(1)), int(bar.group(2))) == (sent, sent)
