"""The server's components run in this process on an event loop of their own thread, around
real virtual controls, for tests that step into a job: :class:`Gated` wraps a machine's real
connector and pauses at named steps until the test lets it go on."""

from __future__ import annotations

import asyncio
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sqlalchemy import func, select
from sqlalchemy.orm import Session, sessionmaker

from opendnc.server.app import Server
from opendnc.server.core.status import Progress
from opendnc.server.jobs import queue as jobs
from opendnc.server.kinds.connector import Connector
from opendnc.server.store.models import AuditEntry, Job, JobKind
from tests.server.db_outage import Outage
from tests.server.harness import wait_for


@dataclass
class Gates:
    """Where a job's transfer stops until the test lets it go on."""

    held: set[str] = field(default_factory=set)
    reached: dict[str, threading.Event] = field(default_factory=dict)
    go: dict[str, threading.Event] = field(default_factory=dict)

    def hold(self, step: str) -> None:
        self.held.add(step)
        self.reached[step] = threading.Event()
        self.go[step] = threading.Event()

    async def at(self, step: str) -> None:
        if step in self.held:
            self.held.discard(step)
            self.reached[step].set()
            await asyncio.to_thread(self.go[step].wait, 60)


class Gated:
    """A real connector (the virtual TNC's LSV2) that pauses at the gates."""

    def __init__(self, inner: Connector, gates: Gates) -> None:
        self.inner = inner
        self.gates = gates
        self.listens = inner.listens

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)

    async def send(self, name: str, data: bytes, progress: Progress) -> None:
        await self.gates.at("transfer")
        await self.inner.send(name, data, progress)

    async def verify(self, name: str, data: bytes) -> bool | None:
        await self.gates.at("verify")
        verified = await self.inner.verify(name, data)
        await self.gates.at("finish")  # the executor returns next; then the runner writes
        return verified


class Running:
    """The server's components on an event loop of their own thread."""

    def __init__(self, server: Server) -> None:
        self.server = server
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()
        self.call(server.core.start())

    def call(self, work: Any, timeout: float = 60) -> Any:
        return asyncio.run_coroutine_threadsafe(work, self.loop).result(timeout)

    def stop(self) -> None:
        self.call(self.server.core.stop())
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(10)
        self.loop.close()


PROGRAM = b"%\r\nO01234 (OUTAGE)\r\n" + b"".join(b"G01 X%d. F100.\r\n" % i for i in range(400))
PROGRAM += b"M30\r\n%\r\n"


@dataclass
class Shop:
    server: Server
    running: Running
    gates: Gates
    outage: Outage
    root: Path
    machine: str
    # The test's own connections: the server's wait 1 s for SQLite's lock (db_outage.quicken),
    # and a loaded machine's write can hold it longer (a read of the test failed so in CI).
    sessions: sessionmaker[Session]

    def queue(self, **extra: Any) -> int:
        with self.sessions.begin() as session:
            version = jobs.version_to_send(session, "O01234.nc", None)  # the released one
            job = jobs.enqueue(session, JobKind.SEND, self.machine, actor="test", version=version)
            for key, value in extra.items():
                setattr(job, key, value)
            return job.id

    def job(self, job_id: int) -> Job:
        with self.sessions() as session:
            return jobs.get_job(session, job_id)

    def ended(self, job_id: int) -> Job:
        def finished() -> Job | None:
            job = self.job(job_id)
            return job if job.state.finished else None

        job: Job = wait_for(f"job {job_id} to end", finished, timeout=90)
        return job

    def audit(self, job_id: int, action: str) -> int:
        with self.sessions() as session:
            count = session.scalar(
                select(func.count(AuditEntry.id)).where(
                    AuditEntry.job_id == job_id, AuditEntry.action == action
                )
            )
            return int(count or 0)
