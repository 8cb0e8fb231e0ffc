"""Typed FastAPI dependencies: how a route gets the server's parts.

The app carries one :class:`~opendnc.server.core.components.Core`; each function here hands a route
one registered component (or a part of one), typed, so a route says
``machines: MachinesDep`` instead of reading an untyped ``app.state`` attribute. The plain
functions take the request, for helpers that are not routes.
"""

from __future__ import annotations

import asyncio
import contextlib
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
from opendnc.server.store.health import WATCH_INTERVAL, WATCH_TIMEOUT, DatabaseHealth

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
    transactions never take SQLite's write lock, for reads, and its health, watched by a task
    while the server runs (a silent database is noticed without a request waiting for it);
    a component."""

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
        # the watch's pace (db_health.py); a test may quicken it before the server starts
        self.watch_interval = WATCH_INTERVAL
        self.watch_timeout = WATCH_TIMEOUT
        self._watch: asyncio.Task[None] | None = None

    async def start(self) -> None:
        """Start watching the database's health (it was migrated when the server was built).

        Only a database across a network link can go silent; SQLite is a file of this
        process, whose statements fail or answer. Watched, a busy machine's slow thread pool
        would be taken for an outage and every request refused for nothing."""
        if self.engine.dialect.name == "sqlite":
            return
        self._watch = asyncio.create_task(
            self.health.watch(self.watch_interval, self.watch_timeout), name="database-watch"
        )

    async def stop(self) -> None:
        """Stop the watch (the engine is disposed by whoever built the server)."""
        task, self._watch = self._watch, None
        if task is not None:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task


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
