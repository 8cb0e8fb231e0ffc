"""What `opendnc haas` tells a new user: help texts and the safety refusal of `haas dnc`."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from opendnc.cli.main import app

runner = CliRunner()


@pytest.mark.parametrize("command", [["haas", "share", "push"], ["haas", "dnc"]])
def test_json_help_of_non_query_commands_speaks_of_the_result(command: list[str]) -> None:
    # these commands send no Q query, so "parsed reply" would mislead
    result = runner.invoke(app, [*command, "--help"], env={"COLUMNS": "200"})
    assert result.exit_code == 0
    assert "Print the result as JSON" in result.output
    assert "parsed reply" not in result.output


def test_dnc_without_unsafe_is_one_readable_sentence(tmp_path: Path) -> None:
    program = tmp_path / "big.nc"
    program.write_text("%\nO1\nM30\n%\n")
    result = runner.invoke(app, ["haas", "dnc", str(program), "--port", "/dev/null-opendnc"])
    assert result.exit_code == 1
    assert "drip-feeding big.nc (it runs on the machine) can change machine behaviour" in (
        result.output
    )
