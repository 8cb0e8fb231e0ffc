"""Typed FastAPI dependencies: how a route gets the server's parts.

The app carries one :class:`~opendnc.server.core.components.Core`; each function here hands a route
one registered component (or a part of one), typed, so a route says
``machines: MachinesDep`` instead of reading an untyped ``app.state`` attribute. The plain
functions take the request, for helpers that are not routes.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Annotated

from fastapi import Depends, Request
from sqlalchemy import Engine
from sqlalchemy.orm import Session, sessionmaker

from opendnc.server.access.key_use import KeyUse
from opendnc.server.core.components import core_of
from opendnc.server.core.loopwatch import LoopWatch
from opendnc.server.jobs.runner import JobRunner
from opendnc.server.machines.dprnt_capture import DprntCapture
from opendnc.server.machines.state import Machines
from opendnc.server.store.db import read_only
from opendnc.server.store.health import DatabaseHealth

if TYPE_CHECKING:
    from opendnc.server.machines.timeline import Timeline
    from opendnc.server.outputs.parts import Outputs

__all__ = [
    "Database",
    "DatabaseDep",
    "DprntDep",
    "LoopWatchDep",
    "MachinesDep",
    "OutputsDep",
    "RunnerDep",
    "TimelineDep",
    "database",
    "dprnt",
    "key_use",
    "loopwatch",
    "machines",
    "outputs",
    "runner",
    "timeline",
]


class Database:
    """The server's database as routes use it: a session factory for writes and one whose
    transactions never take SQLite's write lock, for reads; a component."""

    name = "database"
    needs: tuple[str, ...] = ()

    def __init__(
        self, engine: Engine, sessions: sessionmaker[Session], *, needs: tuple[str, ...] = ()
    ) -> None:
        # ("server-lock",) on PostgreSQL: every user of the database stops before the lock goes
        self.needs = needs
        self.engine = engine
        self.sessions = sessions
        self.reads = read_only(sessions)
        self.health = DatabaseHealth(engine)  # answers, or an outage since when and why

    async def start(self) -> None:
        """Nothing to start (the database was migrated when the server was built)."""

    async def stop(self) -> None:
        """Nothing to stop (the engine is disposed by whoever built the server)."""


def database(request: Request) -> Database:
    """The server's :class:`Database`."""
    return core_of(request.app).get(Database)


def machines(request: Request) -> Machines:
    """Every machine's live state and the way to wake its task."""
    return core_of(request.app).get(Machines)


def runner(request: Request) -> JobRunner:
    """The job runner."""
    return core_of(request.app).get(JobRunner)


def timeline(request: Request) -> Timeline:
    """The status timeline."""
    from opendnc.server.outputs.parts import TimelineRecorder  # the web package imports this module

    return core_of(request.app).get(TimelineRecorder).timeline


def outputs(request: Request) -> Outputs:
    """The open outputs (MQTT, MTConnect)."""
    from opendnc.server.outputs.parts import Outputs

    return core_of(request.app).get(Outputs)


def loopwatch(request: Request) -> LoopWatch:
    """The event loop's stall watch."""
    return core_of(request.app).get(LoopWatch)


def key_use(request: Request) -> KeyUse:
    """Where requests note the keys they used (written once a minute)."""
    return core_of(request.app).get(KeyUse)


def dprnt(request: Request) -> DprntCapture:
    """DPRNT capture (each listener's last word)."""
    return core_of(request.app).get(DprntCapture)


DatabaseDep = Annotated[Database, Depends(database)]
MachinesDep = Annotated[Machines, Depends(machines)]
RunnerDep = Annotated[JobRunner, Depends(runner)]
TimelineDep = Annotated["Timeline", Depends(timeline)]
OutputsDep = Annotated["Outputs", Depends(outputs)]
LoopWatchDep = Annotated[LoopWatch, Depends(loopwatch)]
DprntDep = Annotated[DprntCapture, Depends(dprnt)]
