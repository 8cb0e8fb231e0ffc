"""The runner keeps its jobs through database outages: the database is cut at each step of a
job (claim, transfer, verify, finish) on PostgreSQL and on SQLite, and every job still ends
exactly once, on a server that goes on serving the machine. A cancel written to the job's row
by anyone reaches the running job (the row is the only truth)."""

from __future__ import annotations

from collections.abc import Callable
from datetime import timedelta

import pytest

from tests.peers import require_module

require_module("fastapi")

from opendnc.server.jobs import queue as jobs  # noqa: E402
from opendnc.server.store.models import JobState, utcnow  # noqa: E402
from tests.server.harness import wait_for  # noqa: E402
from tests.server.inproc_server import PROGRAM, Shop  # noqa: E402

STEPS = ("transfer", "verify", "finish")


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
        outages = shop.server.runner.outages
        wait_for("the job's end to meet the outage", lambda: outages["recording"] > 0)
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
    # due later than the queueing and the cut take even on a loaded machine (a job that fell
    # due before the cut would be claimed at once and meet the outage at its end instead), and
    # woken well before a cluster server would stop serving its machines in the outage (the
    # default 10 s lease: at the earliest 4.2 s after the cut)
    due = utcnow() + timedelta(seconds=1.5)
    job_id = shop.queue(not_before=due)
    shop.outage.cut()
    assert utcnow() < due, "the cut came after the job fell due: the test proves nothing"
    try:
        wait_for("the job to fall due", lambda: utcnow() > due + timedelta(seconds=0.2))
        shop.server.machines.wake(shop.machine)  # as the API would: the claim meets the outage
        outages = shop.server.runner.outages
        wait_for("the claim to meet the outage", lambda: outages["claiming"] > 0)
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


def test_a_machine_released_mid_job_gets_its_job_handed_back(shop: Shop) -> None:
    # What a server does when another takes the machine over (several servers, one database):
    # the job it was running is not left "running" for nobody.
    shop.gates.hold("transfer")
    job_id = shop.queue()
    shop.server.machines.wake(shop.machine)
    assert shop.gates.reached["transfer"].wait(30)
    shop.running.call(shop.server.fleet.release(shop.machine))
    shop.gates.go["transfer"].set()  # the released task's worker thread may finish now
    assert shop.machine not in shop.server.fleet.served

    def handed_back() -> bool:
        job = shop.job(job_id)
        return job.state is JobState.QUEUED and "lost track" in job.error

    wait_for("the sweep to hand the job back", handed_back)
    shop.running.loop.call_soon_threadsafe(shop.server.fleet.serve, shop.machine)
    job = shop.ended(job_id)
    assert (job.state, job.attempts) == (JobState.DONE, 2)
    assert _loaded(shop) == PROGRAM
