"""`opendnc lsv2` run in-process for the serial-line tests, which compare its answers over a
serial line with those over TCP."""

from __future__ import annotations

from typer.testing import CliRunner

from opendnc.cli.main import app
from opendnc.sim.tnc import TncHandle

runner = CliRunner()


def lsv2_ok(*args: str) -> str:
    """Run `opendnc lsv2 ARGS`; a non-zero exit fails the test. Returns what it printed."""
    result = runner.invoke(app, ["lsv2", *args])
    assert result.exit_code == 0, (result.stdout, result.stderr, result.exception)
    return result.stdout


def lsv2_over_tcp(tnc: TncHandle, *args: str) -> str:
    """`opendnc lsv2 --port P ARGS` against the virtual control's own TCP port."""
    return lsv2_ok("--port", str(tnc.port), *args)
