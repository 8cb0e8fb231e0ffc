"""A serial port that reads nothing at once (an adapter pulled out, the other end of a cable
gone) does not make the machine's loop spin: between two listens a quarter of the poll
interval passes, whatever the listen took (seen: a server at 55 % of a core for 45 minutes
after its cable's far end closed)."""

from __future__ import annotations

import threading
import time
from pathlib import Path

from opendnc.server.app import build
from opendnc.server.config.shop import MachineConfig, parse_config
from opendnc.server.core.status import MachineStatus
from opendnc.server.kinds.connector import Connector, Reception
from opendnc.server.kinds.registry import connector_for
from opendnc.server.store.models import utcnow
from tests.server.harness import wait_for
from tests.server.inproc_server import Running

POLL = 0.4


class _DeadPort:
    """A listening connector whose every listen comes back at once with nothing."""

    listens = True

    def __init__(self, inner: Connector) -> None:
        self.inner = inner
        self.listened = 0
        self.lock = threading.Lock()

    def __getattr__(self, name: str) -> object:
        return getattr(self.inner, name)

    async def connect(self) -> None:
        return None

    async def close(self) -> None:
        return None

    async def status(self) -> MachineStatus:
        return MachineStatus(at=utcnow(), available=True)

    async def listen(self, seconds: float) -> Reception | None:
        with self.lock:
            self.listened += 1
        return None


def test_a_port_that_reads_nothing_at_once_does_not_spin_the_loop(tmp_path: Path) -> None:
    config = parse_config(
        f"""
[[machines]]
name = "vf2"
kind = "haas_serial"
serial = "socket://127.0.0.1:1"
poll_interval = {POLL}
""",
        base=tmp_path,
    )
    ports: list[_DeadPort] = []

    def dead(machine: MachineConfig) -> Connector:
        port = _DeadPort(connector_for(machine))
        ports.append(port)
        return port  # type: ignore[return-value]

    server = build(config, database=f"sqlite:///{tmp_path / 'db.sqlite'}", connector_factory=dead)
    running = Running(server)
    try:
        wait_for("the machine online", lambda: server.machines.machines["vf2"].online)
        start, before = time.monotonic(), ports[0].listened
        time.sleep(2 * POLL)
        rate = (ports[0].listened - before) / (time.monotonic() - start)
    finally:
        running.stop()
        server.engine.dispose()
    # a quarter of the interval between listens: at most 10 a second here (spinning: thousands)
    assert rate <= 4 / POLL + 1, rate
