"""The runner keeps its jobs through database outages: the database is cut at each step of a
job (claim, transfer, verify, finish) on PostgreSQL and on SQLite, and every job still ends
exactly once, on a server that goes on serving the machine. A cancel written to the job's row
by anyone reaches the running job (the row is the only truth)."""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from datetime import timedelta
from pathlib import Path
from typing import Any

import pytest

from tests.peers import require_module

require_module("fastapi")

from sqlalchemy import func, select  # noqa: E402

from opendnc.server import jobs, library  # noqa: E402
from opendnc.server.app import Server, build  # noqa: E402
from opendnc.server.config import MachineConfig, parse_config  # noqa: E402
from opendnc.server.kinds import connector_for  # noqa: E402
from opendnc.server.machines.base import Connector, Progress  # noqa: E402
from opendnc.server.store.models import AuditEntry, Job, JobState, utcnow  # noqa: E402
from opendnc.sim.fleet import server_config  # noqa: E402
from tests.server.db_outage import Outage  # noqa: E402
from tests.server.harness import wait_for  # noqa: E402
from tests.server.test_from_the_control import FleetThread  # noqa: E402

PROGRAM = b"%\r\nO01234 (OUTAGE)\r\n" + b"".join(b"G01 X%d. F100.\r\n" % i for i in range(400))
PROGRAM += b"M30\r\n%\r\n"
STEPS = ("transfer", "verify", "finish")


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


@dataclass
class Shop:
    server: Server
    running: Running
    gates: Gates
    outage: Outage
    root: Path
    machine: str

    def queue(self, **extra: Any) -> int:
        with self.server.sessions.begin() as session:
            job = jobs.send_program(session, "O01234.nc", [self.machine], actor="test")[0]
            for key, value in extra.items():
                setattr(job, key, value)
            return job.id

    def job(self, job_id: int) -> Job:
        with self.server.sessions() as session:
            return jobs.get_job(session, job_id)

    def ended(self, job_id: int) -> Job:
        def finished() -> Job | None:
            job = self.job(job_id)
            return job if job.state.finished else None

        job: Job = wait_for(f"job {job_id} to end", finished, timeout=90)
        return job

    def audit(self, job_id: int, action: str) -> int:
        with self.server.sessions() as session:
            count = session.scalar(
                select(func.count(AuditEntry.id)).where(
                    AuditEntry.job_id == job_id, AuditEntry.action == action
                )
            )
            return int(count or 0)


@pytest.fixture
def shop(db_url: str, tmp_path: Path) -> Iterator[Shop]:
    fleet = FleetThread(tmp_path / "machines", tnc=1, haas=0)
    outage = Outage(db_url)
    gates = Gates()
    running = None
    try:
        text = server_config(fleet.fleet, poll_interval=0.2, library=tmp_path / "lib")

        def gated(machine: MachineConfig) -> Connector:
            return Gated(connector_for(machine), gates)

        server = build(
            parse_config(text, base=tmp_path),
            database=db_url,
            connector_factory=gated,
            sweep_interval=0.3,
            retry_backoff=0.2,
        )
        outage.quicken(server.engine)
        with server.sessions.begin() as session:
            library.add_version(session, "O01234.nc", PROGRAM, author="test")
            library.release(session, "O01234.nc", 1, actor="test")
        running = Running(server)
        machine = fleet.fleet.machines[0]
        wait_for("the TNC online", lambda: server.machines.machines[machine.name].online)
        yield Shop(server, running, gates, outage, machine.root, machine.name)
    finally:
        outage.close()
        if running is not None:
            running.stop()
            running.server.engine.dispose()
        fleet.stop()


def _loaded(shop: Shop) -> bytes:
    return (shop.root / "TNC" / "nc_prog" / "O01234.nc").read_bytes()


def _a_later_job_runs(shop: Shop) -> None:
    """The machine is not stranded: the next job runs to the end."""
    later = shop.queue()
    shop.server.machines.wake(shop.machine)
    assert shop.ended(later).state is JobState.DONE


@pytest.mark.parametrize("step", STEPS)
def test_a_database_outage_during_a_job_ends_it_exactly_once(shop: Shop, step: str) -> None:
    shop.gates.hold(step)
    job_id = shop.queue()
    shop.server.machines.wake(shop.machine)
    assert shop.gates.reached[step].wait(30), f"the job never reached {step}"
    shop.outage.cut()
    try:
        shop.gates.go[step].set()
        # The runner met the outage when it wrote the job's end (and kept the job meanwhile).
        wait_for("the runner to meet the outage", lambda: shop.server.runner.database_error)
        assert shop.server.machines.machines[shop.machine].job_id == job_id
    finally:
        shop.outage.restore()
    job = shop.ended(job_id)
    assert (job.state, job.attempts) == (JobState.DONE, 1)
    assert shop.audit(job_id, "job.start") == 1
    assert shop.audit(job_id, "job.send") == 1  # one end, recorded once
    assert _loaded(shop) == PROGRAM
    wait_for(
        "the machine to let go of the job",
        lambda: shop.server.machines.machines[shop.machine].job_id is None,
    )
    _a_later_job_runs(shop)


def test_a_database_outage_at_the_claim_delays_the_job_and_runs_it_once(shop: Shop) -> None:
    due = utcnow() + timedelta(seconds=0.5)
    job_id = shop.queue(not_before=due)
    shop.outage.cut()
    try:
        wait_for("the job to fall due", lambda: utcnow() > due + timedelta(seconds=0.2))
        shop.server.machines.wake(shop.machine)  # as the API would: the claim meets the outage
        wait_for("the runner to meet the outage", lambda: shop.server.runner.database_error)
    finally:
        shop.outage.restore()
    job = shop.ended(job_id)
    assert job.state is JobState.DONE
    assert shop.audit(job_id, "job.start") == job.attempts
    assert shop.audit(job_id, "job.send") == 1
    assert _loaded(shop) == PROGRAM
    _a_later_job_runs(shop)


def test_a_cancel_in_the_jobs_row_stops_the_running_transfer(shop: Shop) -> None:
    shop.gates.hold("transfer")
    job_id = shop.queue()
    shop.server.machines.wake(shop.machine)
    assert shop.gates.reached["transfer"].wait(30)
    # Written straight into the row, as another server's API would: no call into this process.
    with shop.server.sessions.begin() as session:
        jobs.cancel(session, job_id, actor="elsewhere")
    seen: Callable[[], bool] = lambda: shop.server.runner.cancel_seen(job_id)  # noqa: E731
    wait_for("the runner to read the cancel", seen)
    shop.gates.go["transfer"].set()
    job = shop.ended(job_id)
    assert job.state is JobState.CANCELLED
    assert "cancelled" in job.error
    assert not (shop.root / "TNC" / "nc_prog" / "O01234.nc").exists()
    _a_later_job_runs(shop)
