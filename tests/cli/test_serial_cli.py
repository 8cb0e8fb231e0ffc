"""`opendnc serial`: profiles as JSON, refusals as one line before any port opens."""

from __future__ import annotations

import json
from pathlib import Path

import typer
from typer.testing import CliRunner

from opendnc.cli.main import app


def test_profiles_json_lists_every_profile_with_its_port() -> None:
    result = CliRunner().invoke(app, ["serial", "profiles", "--json"])
    assert result.exit_code == 0, result.output
    rows = {row["name"]: row for row in json.loads(result.stdout)}
    assert rows["fanuc-0i"]["port"] == {"bytesize": 8, "parity": "N", "stopbits": 2.0}
    assert rows["fanuc-0i"]["software_parity"] is True
    assert rows["siemens-840d"]["framing"] == "siemens"
    assert rows["okuma-osp"]["leader"] == 600


def test_dnc_is_refused_without_unsafe(tmp_path: Path) -> None:
    program = tmp_path / "O0001.nc"
    program.write_text("%\nO0001\nG00 X0.\nM30\n%\n")
    args = ["serial", "dnc", str(program), "--port", str(tmp_path / "no-port")]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 1
    assert "--unsafe" in result.output
    assert "is locked" in result.output


def test_a_character_without_eia_code_is_named(tmp_path: Path) -> None:
    program = tmp_path / "O0001.nc"
    program.write_text("%\nO0001\n#100=1\nM30\n%\n")
    args = ["serial", "send", str(program), "--code", "eia", "--port", str(tmp_path / "tty")]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 1
    assert "'#' at line 3, column 1 has no EIA code" in result.output  # before any port opens


def _options(command: str) -> set[str]:
    from opendnc.cli.serial import app as serial_app

    click_command = typer.main.get_command(serial_app).commands[command]  # type: ignore[attr-defined]
    return {name for param in click_command.params for name in param.opts}


def test_each_command_offers_the_profile_changes_it_uses() -> None:
    changes = {"--baud", "--line", "--code", "--eob", "--flow", "--tv-check", "--wait-dc1"}
    changes |= {"--leader", "--punch-dc2"}
    assert changes <= _options("send")
    assert changes - _options("dnc") == {"--punch-dc2"}  # a drip-feed is never punched
    assert changes - _options("recv") == {"--eob", "--flow", "--wait-dc1", "--leader"}
    for command in ("send", "dnc", "recv"):
        assert {"--port", "-p", "--profile", "--json"} <= _options(command)


def test_a_bad_line_is_refused_before_any_port_opens(tmp_path: Path) -> None:
    program = tmp_path / "O0001.nc"
    program.write_text("%\nO0001\nG00 X0.\nM30\n%\n")
    port = ["--port", str(tmp_path / "no-port"), "--line", "7Q2"]
    for args in (["send", str(program)], ["dnc", str(program), "--unsafe"], ["recv", "."]):
        result = CliRunner().invoke(app, ["serial", *args, *port])
        assert result.exit_code == 1, (args, result.output)
        assert "unknown parity 'Q'" in result.output, args
