"""`opendnc haas macro set` refuses locally, with the reason, what a Haas would refuse.

Nothing listens on the port: a command that tried to connect would report a connection error
instead of the reason, so each case shows the refusal happens before anything goes out.
"""

from __future__ import annotations

import socket

import pytest
from typer.testing import CliRunner

from opendnc.cli.main import app

runner = CliRunner()


@pytest.fixture(scope="module")
def dead_port() -> str:
    with socket.create_server(("127.0.0.1", 0)) as sock:
        return str(sock.getsockname()[1])  # closed again: connecting is refused


@pytest.mark.parametrize(
    ("var", "value", "reason"),
    [
        ("3901", "-1", "#3901 (M30 counter 1) holds 0 to 2147483647, not -1"),
        ("3901", "99999999999999999999", "holds 0 to 2147483647"),
        ("3902", "-7.5", "#3902 (M30 counter 2) holds whole numbers only"),
        ("1000", "1", "#1000 is read-only (discrete inputs)"),
        ("1063", "0", "#1063 is read-only (discrete inputs)"),
        ("3020", "0", "#3020 is read-only (power-on timer)"),
        ("3026", "5", "#3026 is read-only (tool in the spindle)"),
        ("4001", "0", "#4001 is read-only (modal information"),
        ("4120", "0", "#4120 is read-only (modal information"),
        ("5081", "0", "#5081 is read-only (tool length offset in effect)"),
        ("3000", "15", "#3000 is the programmable alarm"),
    ],
)
def test_refused_locally_with_the_reason(dead_port: str, var: str, value: str, reason: str) -> None:
    args = ["haas", "macro", "set", var, value, "--port", dead_port]
    result = runner.invoke(app, [*args, "--unsafe", "--any-variable"])
    assert result.exit_code == 1, result.output
    assert reason in " ".join(result.output.split()), result.output
    assert "connect" not in result.output
    # the control's reason comes first, even without the opt-ins
    locked = runner.invoke(app, args)
    assert reason in " ".join(locked.output.split()), locked.output


def test_an_acceptable_write_still_needs_the_opt_in(dead_port: str) -> None:
    result = runner.invoke(app, ["haas", "macro", "set", "3901", "12", "--port", dead_port])
    assert result.exit_code == 1
    assert "locked" in result.output
    assert "connect" not in result.output
