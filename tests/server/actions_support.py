"""The actions layer without a running server: its services over a database and a runner
that only knows the machines' configuration (nothing is connected, nothing runs)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from sqlalchemy.orm import Session, sessionmaker

from opendnc.server.actions import Services
from opendnc.server.config.shop import LibraryConfig, MachineConfig, ServerConfig, ShopConfig
from opendnc.server.core.events import EventBus
from opendnc.server.machines.state import MachineState
from opendnc.server.store.db import read_only


@dataclass
class StillRunner:
    """The runner's face the actions see; records the machines it is asked to wake."""

    config: ShopConfig
    machines: dict[str, MachineState]
    bus: EventBus = field(default_factory=EventBus)
    woken: list[str] = field(default_factory=list)

    def wake(self, machine: str) -> None:
        self.woken.append(machine)


def services(sessions: sessionmaker[Session], machines: Sequence[MachineConfig]) -> Services:
    """Services over ``sessions`` for ``machines`` (offline: nothing connects)."""
    library = LibraryConfig(path=Path("lib"), inbox=Path("inbox"), archive=Path("archive"))
    config = ShopConfig(server=ServerConfig(), library=library, machines=tuple(machines))
    runner = StillRunner(config, {m.name: MachineState(m) for m in machines})
    return Services(sessions, read_only(sessions), runner)
