"""`opendnc haas q` with a code the control rejects fails, on both control types."""

from __future__ import annotations

from typer.testing import CliRunner

from opendnc.cli.main import app
from opendnc.sim.haas import SimHaasThread


def test_rejected_q_code_exits_nonzero_with_a_clear_message(sim: SimHaasThread) -> None:
    assert sim.sim.mdc is not None
    port = str(sim.sim.mdc.port)
    known = CliRunner().invoke(app, ["haas", "q", "Q500", "--port", port])
    assert known.exit_code == 0, known.output
    rejected = CliRunner().invoke(app, ["haas", "q", "Q999", "--port", port])
    assert rejected.exit_code == 1, rejected.output
    assert "the control rejected Q999" in rejected.output
    assert len(rejected.output.strip().splitlines()) == 1
