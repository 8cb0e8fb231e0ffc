"""Jobs across a change of a machine's server, on the real databases: the new server ends
what the old one left running exactly once (a load queued again, a drip-feed interrupted at
its recorded line), the old one can no longer touch the job (fencing by the lease's epoch),
and a machine with a running job is never handed over."""

from __future__ import annotations

import time

from sqlalchemy import select
from sqlalchemy.orm import Session, sessionmaker

from opendnc.server.jobs import queue as jobs
from opendnc.server.kinds.lsv2 import Lsv2Machine
from opendnc.server.library import versions as library
from opendnc.server.machines.leases import Leases, holds
from opendnc.server.store.models import AuditEntry, JobKind, JobState

MACHINES = {"mill-1": frozenset[str](), "mill-2": frozenset[str]()}


def _shop(sessions: sessionmaker[Session]) -> None:
    with sessions.begin() as session:
        jobs.sync_machines(
            session, [Lsv2Machine(name=m, host="127.0.0.1", port=19000) for m in MACHINES]
        )
        library.add_version(session, "P1.H", b"0 BEGIN PGM P1 MM\r\n", author="t")


def _running(sessions: sessionmaker[Session], machine: str, kind: JobKind, worker: str) -> int:
    with sessions.begin() as session:
        version = library.get_version(session, "P1.H", 1)
        job = jobs.enqueue(session, kind, machine, actor="t", version=version)
        job_id = job.id
    with sessions.begin() as session:
        claimed = jobs.claim(session, machine, worker)
        assert claimed is not None
        assert claimed.id == job_id
    return job_id


def _take_after_expiry(sessions: sessionmaker[Session], dead: Leases, machine: str) -> Leases:
    """``dead`` stops renewing; a second server takes ``machine`` once the lease ran out."""
    new = Leases(sessions, "dnc-2", MACHINES, ttl=dead.ttl.total_seconds())
    deadline = time.monotonic() + 10
    while machine not in new.renew().held:
        assert time.monotonic() < deadline, "the lease was never taken"
        time.sleep(0.05)
    return new


def test_the_new_server_ends_the_old_ones_jobs_once(sessions: sessionmaker[Session]) -> None:
    _shop(sessions)
    old = Leases(sessions, "dnc-1", MACHINES, ttl=0.5)
    old.renew()
    epoch = dict(old.renew().epochs)
    load = _running(sessions, "mill-1", JobKind.SEND, "dnc-1")
    feed = _running(sessions, "mill-2", JobKind.DRIPFEED, "dnc-1")
    with sessions.begin() as session:
        assert holds(session, "mill-2", "dnc-1", epoch["mill-2"])
        jobs.note_progress(session, feed, line=42, nbytes=900)
    new = _take_after_expiry(sessions, old, "mill-1")
    _take_after_expiry(sessions, old, "mill-2")
    now = new.renew().epochs["mill-1"]
    assert now == epoch["mill-1"] + 1
    with sessions.begin() as session:
        # the old server, back from a pause, cannot finish what it no longer owns
        assert not holds(session, "mill-1", "dnc-1", epoch["mill-1"])
        assert holds(session, "mill-1", "dnc-2", now)
    for _ in range(2):  # a second take-over (a restart, a second taker) changes nothing
        with sessions.begin() as session:
            for machine in MACHINES:
                jobs.take_over(session, machine, "dnc-2")
    with sessions.begin() as session:
        sent, fed = jobs.get_job(session, load), jobs.get_job(session, feed)
        assert (sent.state, sent.not_before, sent.attempts) == (JobState.QUEUED, None, 1)
        # its next run asks the control first whether the old server's transfer got there
        assert sent.params[jobs.TAKEN_OVER_FROM] == "dnc-1"
        assert jobs.TAKEN_OVER_FROM not in fed.params
        assert (fed.state, fed.line, fed.bytes_done) == (JobState.INTERRUPTED, 42, 900)
        assert "at line 42" in fed.error
        assert "dnc-1" in fed.error
        rows = session.scalars(select(AuditEntry).where(AuditEntry.action == "job.takeover"))
        trail = sorted((r.job_id, r.actor, r.result, r.detail["previous"]) for r in rows)
        assert trail == [
            (load, "dnc-2", "queued again", "dnc-1"),
            (feed, "dnc-2", "interrupted", "dnc-1"),
        ]
        # the queued load is claimed again, by its new server
        again = jobs.claim(session, "mill-1", "dnc-2")
        assert again is not None
        assert again.id == load
        assert again.attempts == 2
        # a person's retry of it (after it failed) sends it, without asking the control first
        jobs.fail(session, load, "refused", retryable=False)
        retried = jobs.retry(session, load, actor="t")
        assert retried.params["retry_of"] == load
        assert jobs.TAKEN_OVER_FROM not in retried.params


def test_a_job_this_server_runs_is_kept(sessions: sessionmaker[Session]) -> None:
    _shop(sessions)
    job = _running(sessions, "mill-1", JobKind.SEND, "dnc-1")
    with sessions.begin() as session:
        assert jobs.take_over(session, "mill-1", "dnc-1", keep={job}) == []
        assert jobs.get_job(session, job).state is JobState.RUNNING


def test_a_machine_with_a_running_job_is_not_handed_over(
    sessions: sessionmaker[Session],
) -> None:
    _shop(sessions)
    a = Leases(sessions, "dnc-1", MACHINES, ttl=5)
    a.renew()
    assert a.held == set(MACHINES)
    job_ids = [_running(sessions, m, JobKind.SEND, "dnc-1") for m in MACHINES]
    b = Leases(sessions, "dnc-2", MACHINES, ttl=5)
    for _ in range(3):  # dnc-2 joins: one machine is its own now, but both run a job
        b.renew()
        a.renew()  # (told the machines are idle: the database's running job decides)
    assert a.held == set(MACHINES)
    assert not b.held
    with sessions.begin() as session:
        for job_id in job_ids:
            jobs.finish(session, job_id)
    a.renew()
    b.renew()
    assert len(a.held) == len(b.held) == 1


def test_a_continuation_goes_to_the_head_of_the_queue_once_the_position_is_in(
    sessions: sessionmaker[Session],
) -> None:
    _shop(sessions)
    feed = _running(sessions, "mill-2", JobKind.DRIPFEED, "dnc-1")
    with sessions.begin() as session:
        version = library.get_version(session, "P1.H", 1)
        waiting = jobs.enqueue(session, JobKind.SEND, "mill-2", actor="t", version=version).id
        jobs.take_over(session, "mill-2", "dnc-2")
        assert jobs.get_job(session, feed).params[jobs.AWAITING_POSITION] == "dnc-1"
        assert not jobs.position_said(session, feed)
    with sessions.begin() as session:
        follow = jobs.resume(session, feed, actor="dnc-1", offset=19, written=b"G1 ", line=2).id
    with sessions.begin() as session:
        assert jobs.position_said(session, feed)  # the new server stops waiting
        cont = jobs.get_job(session, follow)
        assert cont.params[jobs.RESUME] == {"offset": 19, "written": "473120"}  # "G1 " in hex
        assert (cont.params[jobs.RESUME_OF], cont.params["from_line"]) == (feed, 2)
        (row,) = session.scalars(select(AuditEntry).where(AuditEntry.action == "job.resume"))
        assert (row.actor, row.job_id, row.detail["resume_of"]) == ("dnc-1", follow, feed)
        # before the load that was queued first
        claimed = jobs.claim(session, "mill-2", "dnc-2")
        assert claimed is not None
        assert claimed.id == follow
        assert waiting != follow
        # a person's retry of it starts at its line, never at the old position
        jobs.fail(session, follow, "broke", retryable=False)
        again = jobs.retry(session, follow, actor="t")
        assert jobs.RESUME not in again.params
        assert jobs.RESUME_OF not in again.params
