"""A machine whose connector cannot be made (its kind's module needs a library that is not
installed) shows that as its error and is tried again, instead of its task ending unseen."""

from __future__ import annotations

from pathlib import Path

from opendnc.server.app import build
from opendnc.server.config.shop import MachineConfig, parse_config
from opendnc.server.kinds.connector import Connector
from opendnc.server.kinds.registry import connector_for
from tests.server.harness import wait_for
from tests.server.inproc_server import Running


def test_a_connector_that_cannot_be_made_is_the_machines_error_and_is_tried_again(
    tmp_path: Path,
) -> None:
    config = parse_config(
        """
[[machines]]
name = "vf2"
kind = "haas_serial"
serial = "socket://127.0.0.1:1"
""",
        base=tmp_path,
    )
    tries: list[str] = []
    shown: list[tuple[str | None, bool]] = []  # the machine's error and online flag, try 2

    def missing_once(machine: MachineConfig) -> Connector:
        tries.append(machine.name)
        if len(tries) == 1:
            raise ModuleNotFoundError("No module named 'serial'", name="serial")
        # read here, in the machine's own loop: what it showed between the two tries (a
        # poll from the test can come after the link's own error has replaced it)
        state = server.machines.machines[machine.name]
        shown.append((state.last_error, state.online))
        return connector_for(machine)

    server = build(
        config, database=f"sqlite:///{tmp_path / 'db.sqlite'}", connector_factory=missing_once
    )
    running = Running(server)
    try:
        state = server.machines.machines["vf2"]
        # the next try makes the connector (nothing listens on port 1, so it stays offline)
        wait_for("a second try", lambda: len(tries) == 2)
        assert shown == [("No module named 'serial'", False)]
        wait_for("the link's own error", lambda: state.last_error != "No module named 'serial'")
        assert len(tries) == 2  # made once, then kept across the link's own retries
    finally:
        running.stop()
        server.engine.dispose()
