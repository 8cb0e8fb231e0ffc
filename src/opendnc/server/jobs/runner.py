"""The job runner: claims a machine's due jobs, runs each through its kind's executor, and
records how it ended, whatever the database does meanwhile.

A machine's task (:mod:`opendnc.server.fleet.tasks`) calls :meth:`JobRunner.run_due` when it is
woken, on its own connector, between two status polls. Woken means: the API queued a job in
this process, or the runner's sweep (one query for the whole shop every ``sweep_interval``)
found due jobs (queued by another server, retries whose backoff expired).

Every state change the runner makes is retried until the database answers (docs/server.md#jobs):
a finished transfer whose ``done`` cannot be written keeps its machine (no new claim) and is
written when the database is back; a write that went through although its answer was lost is
recognised by re-reading the job. A claim whose answer was lost is found by the sweep, which
hands any job this server holds as running but does not run back to the queue (a load) or ends
it interrupted (a drip-feed). Cancels are read from the job's row (``cancel_requested``) while
it runs, so a cancel served by any process reaches it.

Several servers on one database (docs/server.md#several-servers): a runner with a ``fence``
(:class:`opendnc.server.cluster.cluster.Cluster`) claims jobs only for machines whose lease this
server holds, and checks the lease's epoch in the same transaction as every change it makes
to a job (claim, progress, end): a server that lost a machine while it was paused cannot
finish a job the machine's new server has already taken over (:func:`jobs.take_over`).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import socket
import time
from collections import Counter
from collections.abc import Callable, Iterable, Mapping
from typing import Any, Protocol, TypeVar

from sqlalchemy import select
from sqlalchemy.exc import DBAPIError, InterfaceError, OperationalError
from sqlalchemy.exc import TimeoutError as PoolTimeout
from sqlalchemy.orm import Session, sessionmaker

from opendnc.errors import DncError, RemoteProtocolError, TransferError, TransportError
from opendnc.server.core.components import cancel_and_wait
from opendnc.server.core.errors import NotFound
from opendnc.server.core.events import (
    JobFinished,
    JobProgress,
    JobQueued,
    JobStarted,
    TransferProgress,
)
from opendnc.server.jobs import queue as jobs
from opendnc.server.jobs.executors import (
    Claimed,
    DripFeedBroken,
    Executor,
    JobCancelled,
    JobRun,
    unknown_kind,
)
from opendnc.server.kinds.connector import Connector
from opendnc.server.library import versions as library
from opendnc.server.machines.leases import holds
from opendnc.server.machines.state import Machines, MachineState
from opendnc.server.store import audit
from opendnc.server.store.db import read_only
from opendnc.server.store.health import reason
from opendnc.server.store.models import ClusterServer, Job, JobKind, JobState

__all__ = ["Fence", "Fenced", "JobRunner", "LeaseLost", "database_down"]

log = logging.getLogger(__name__)

T = TypeVar("T")
CANCEL_POLL = 0.5  # seconds between two reads of a running job's cancel flag
RETRY_FIRST = 0.2  # seconds before the first retry of a write the database refused
RETRY_MAX = 5.0
SETTLE_WAIT = 2.0  # seconds a machine's task waits for a job's end to be written
RESUME_WAIT = 60.0
"""Seconds a machine taken over in the middle of a drip-feed waits, silent, for the exact
position of the server that fed it (``[server] resume_wait``)."""
POSITION_POLL = 0.5  # seconds between two looks for that position


class LeaseLost(DncError):
    """This server no longer holds the machine's lease: another server has taken it over."""


class Fenced(DncError):
    """This server stopped driving the machine: its lease could not be renewed in time."""


class Fence(Protocol):
    """Which machines this server may act on, and at which lease epoch (several servers)."""

    lock_limit: float  # seconds a transaction holding a lease row may stay silent

    def epoch(self, machine: str) -> int | None:
        """The epoch of this server's live lease on ``machine``; None if it holds none."""


def database_down(exc: BaseException) -> bool:
    """True for errors that say the database cannot be reached or is locked right now (as
    opposed to a bug or a refused change)."""
    if isinstance(exc, OperationalError | InterfaceError | PoolTimeout):
        return True
    return isinstance(exc, DBAPIError) and bool(exc.connection_invalidated)


class JobRunner:
    """Claims and runs jobs; a component (``start`` recovers, ``stop`` ends the sweep)."""

    name = "runner"

    def __init__(
        self,
        machines: Machines,
        sessions: sessionmaker[Session],
        executors: Iterable[Executor],
        *,
        worker: str,
        sweep_interval: float = 5.0,
        retry_backoff: float = 2.0,
        cancel_poll: float = CANCEL_POLL,
        resume_wait: float = RESUME_WAIT,
    ) -> None:
        self.machines = machines
        self.sessions = sessions
        self._reads = read_only(sessions)  # the sweep's queries need not wait for the lock
        self.executors: dict[JobKind, Executor] = {e.kind: e for e in executors}
        self.needs = ("machines", "database", *(e.name for e in self.executors.values()))
        self.worker = worker
        self.sweep_interval = sweep_interval
        self.retry_backoff = retry_backoff
        self.cancel_poll = cancel_poll
        # seconds a machine taken over mid-feed stays silent waiting for the old server's
        # exact position (docs/server.md#a-fenced-drip-feed)
        self.resume_wait = resume_wait
        self.database_error = ""  # the last database failure, until the next success
        self.outages: Counter[str] = Counter()  # failed database work, by what it was doing
        self.running: dict[int, JobRun] = {}  # the jobs this process runs now, by id
        self._claiming: set[str] = set()  # machines whose claim is under way
        self._settling: set[asyncio.Task[None]] = set()
        self._unsettled: set[int] = set()  # jobs whose end waits for the database
        self._sweep: asyncio.Task[None] | None = None
        self.fence: Fence | None = None  # set by the cluster (several servers), else None
        self._epochs: dict[int, int] = {}  # running job -> the lease epoch it was claimed at
        self._lines: dict[int, tuple[int | None, int]] = {}  # drip-feed -> (line, bytes) fed
        self._paused: set[int] = set()  # fenced drip-feeds whose pause is recorded
        # fenced drip-feeds with an exact position not written yet -> their machine: the rest
        # is owed to that control (a continuation will be queued), so it hears nothing else
        self._owing: dict[int, str] = {}

    # -- lifecycle ----------------------------------------------------------------------

    async def start(self) -> None:
        """Make the machines table match the configuration, mark the jobs this server left
        running as interrupted, then sweep for due jobs."""
        config = self.machines.config

        def prepare() -> list[int]:
            with self.sessions.begin() as session:
                jobs.sync_machines(session, config.machines)
                if self.fence is not None:
                    return []  # each machine's server takes its jobs over with its lease
                return [job.id for job in jobs.recover(session, self.worker)]

        for job_id in await asyncio.to_thread(prepare):
            log.warning("job %d was running when the server stopped: interrupted", job_id)
        for state in self.machines.machines.values():
            state.wake.set()  # a first look at the queue
        self._sweep = asyncio.create_task(self._sweeping(), name="job-sweep")

    async def stop(self) -> None:
        """End the sweep; a settle still waiting for the database is given up (the next start
        marks its job interrupted)."""
        tasks = [t for t in (self._sweep, *self._settling) if t is not None]
        self._sweep = None
        await cancel_and_wait(*tasks)

    # -- the database, patiently --------------------------------------------------------

    async def _durably(self, what: str, work: Callable[[Session], T]) -> T:
        """Run ``work`` in a transaction, retrying while the database is away."""
        delay = RETRY_FIRST
        while True:
            try:
                result = await asyncio.to_thread(self._transaction, work)
            except Exception as exc:
                if not database_down(exc):
                    raise
                self._trouble(what, exc)
                await asyncio.sleep(delay)
                delay = min(delay * 2, RETRY_MAX)
                continue
            self.database_error = ""
            return result

    def _transaction(self, work: Callable[[Session], T]) -> T:
        with self.sessions.begin() as session:
            return work(session)

    def _trouble(self, what: str, exc: BaseException) -> None:
        self.outages[what.split(" ", 1)[0]] += 1
        first = reason(exc)
        if not self.database_error:
            log.warning("database unavailable while %s: %s (retrying)", what, first)
        self.database_error = f"{what}: {first}"

    # -- the sweep ------------------------------------------------------------------------

    async def _sweeping(self) -> None:
        while True:
            await asyncio.sleep(self.sweep_interval)
            try:
                due, held = await asyncio.to_thread(self._look)
            except Exception as exc:
                if not database_down(exc):
                    log.exception("job sweep failed")
                else:
                    self._trouble("looking for due jobs", exc)
                continue
            for name in due:
                self.machines.wake(name)
            await self._reconcile(held)

    def _look(self) -> tuple[list[str], list[tuple[int, str]]]:
        with self._reads() as session:
            due = jobs.machines_with_due_jobs(session)
            held = session.execute(
                select(Job.id, Job.machine).where(
                    Job.state == JobState.RUNNING, Job.claimed_by == self.worker
                )
            ).all()
            return due, [(int(i), str(m)) for i, m in held]

    async def _reconcile(self, held: list[tuple[int, str]]) -> None:
        """Hand back the jobs the database says this server runs but no machine task holds
        (a claim whose answer was lost; a machine no longer served here)."""
        for job_id, machine in held:
            state = self.machines.get(machine)
            if machine in self._claiming or (state is not None and state.job_id == job_id):
                continue  # being claimed or run right now (the query may predate it)
            if job_id in self._unsettled:
                continue  # its end is written as soon as the database answers

            def hand_back(session: Session, job_id: int = job_id) -> JobFinished:
                job = jobs.get_job(session, job_id)
                program = job.version.program.name if job.version is not None else None
                number = job.version.number if job.version is not None else None
                fields = (job_id, job.machine, job.kind, program, number)
                if job.state is not JobState.RUNNING or job.claimed_by != self.worker:
                    return JobFinished(*fields, outcome=job.state)
                self._check_lease(session, job.machine, self._epochs.get(job_id))
                reason = "this server lost track of the job (database outage); not run"
                ended = jobs.fail(session, job_id, reason, retryable=True).state
                return JobFinished(*fields, outcome=ended, error=reason)

            try:
                event = await self._durably(f"handing back job {job_id}", hand_back)
            except LeaseLost:
                continue  # the machine's new server takes the job over
            log.warning("job %d was held by no machine task: now %s", job_id, event.outcome)
            self.machines.bus.publish(event)
            self.machines.wake(machine)

    # -- running --------------------------------------------------------------------------

    async def run_due(self, state: MachineState, connector: Connector) -> None:
        """Claim and run ``state``'s due jobs one after the other, until none is due.

        A link error of the machine propagates (its task reconnects); a database that is away
        ends the round (the machine is woken again once it answers).
        """
        while state.job_id is None and await self._run_next(state, connector):
            pass

    async def _run_next(self, state: MachineState, connector: Connector) -> bool:
        name = state.config.name
        self._claiming.add(name)
        try:
            claimed = await asyncio.to_thread(self._claim, name)
        except Exception as exc:
            self._claiming.discard(name)
            if not database_down(exc):
                raise
            self._trouble(f"claiming a job of {name}", exc)
            # The claim may have gone through without its answer: the sweep hands such a
            # job back; this machine looks again once the database answers.
            asyncio.get_running_loop().call_later(RETRY_MAX, self.machines.wake, name)
            return False
        except BaseException:
            self._claiming.discard(name)
            raise
        if claimed is None:
            self._claiming.discard(name)
            return False
        # In the same step of the loop as the discard: the sweep never sees neither.
        state.start_job(claimed.job_id, len(claimed.data) or None, claimed.kind, claimed.name)
        self._claiming.discard(name)
        self.machines.bus.publish(
            JobStarted(*_fields(claimed, name), bytes_total=len(claimed.data) or None)
        )
        # what the server does to the machine is part of its state (a drip-feed: running)
        self.machines.publish(state)
        run = JobRun(
            claimed,
            state,
            connector,
            progress=lambda progress: self._progress(claimed, name, progress),
            check_cancel=lambda: self._cancel_requested(claimed.job_id),
            still_driving=lambda: self._still_driving(claimed, name),
        )
        watch = asyncio.create_task(self._watch_cancel(run), name=f"cancel-watch-{claimed.job_id}")
        self.running[claimed.job_id] = run
        try:
            outcome = await self._execute(run)
        except asyncio.CancelledError:
            # Stopping the server mid-transfer: the next start marks the job interrupted.
            raise
        except Exception as exc:
            fenced = isinstance(exc, Fenced) or isinstance(exc.__cause__, Fenced)
            if fenced or (self.fence is not None and self.fence.epoch(name) is None):
                # stopped by the fence (its own check, or the link it closed under a feed
                # held by XOFF): nothing is written now
                self._fenced_off(run, exc)
                return True
            await self._failed(run, exc)
            if run.link_unknown:
                # A transfer stopped half-way: the control's side of the link is not known.
                await connector.close()
                await connector.connect()
            cause = exc.__cause__ if isinstance(exc, DripFeedBroken) else exc
            if isinstance(cause, TransportError):
                raise exc from cause  # reconnect before the next job
            return True
        finally:
            watch.cancel()
            self.running.pop(claimed.job_id, None)
            self._lines.pop(claimed.job_id, None)
        if run.cancel_requested:
            # The work was done before the cancel could stop it: said so in its audit row.
            outcome["cancel"] = "requested too late: the work was already done"
        await self._settle(run, JobState.DONE, lambda s: self._finish(s, run, outcome))
        return True

    def _claim(self, machine: str) -> Claimed | None:
        epoch = None
        if self.fence is not None:
            epoch = self.fence.epoch(machine)
            if epoch is None:
                return None  # not this server's machine (any more)
        with self.sessions.begin() as session:
            lock = self.fence.lock_limit if self.fence is not None else None
            if epoch is not None and not holds(session, machine, self.worker, epoch, lock):
                return None
            job = jobs.claim(session, machine, self.worker)
            if job is None:
                return None
            if epoch is not None:
                self._epochs[job.id] = epoch
            params = dict(job.params)
            if job.kind is JobKind.REPORT:
                report = str(params.get("report", "")).encode("latin-1")
                return Claimed(
                    job.id, job.kind, str(params.get("name")), report, params, attempt=job.attempts
                )
            if job.kind in jobs.PROGRAM_JOBS:  # send, drip-feed, put_file
                if job.version is None:
                    jobs.fail(session, job.id, "the job names no program", retryable=False)
                    return None
                data = library.content(session, job.version)
                program, number = job.version.program.name, job.version.number
                return Claimed(
                    job.id, job.kind, program, data, params, number, attempt=job.attempts
                )
            return Claimed(
                job.id, job.kind, str(params.get("path", "")), b"", params, attempt=job.attempts
            )

    async def _execute(self, run: JobRun) -> dict[str, Any]:
        executor = self.executors.get(run.job.kind)
        if executor is None:
            raise unknown_kind(run.job.kind)
        return await executor.run(run)

    async def _failed(self, run: JobRun, exc: Exception) -> None:
        reason = str(exc) or type(exc).__name__
        # A broken link or a garbled transfer may go well next time; a refusal will not.
        retryable = isinstance(exc, TransportError | TransferError | RemoteProtocolError)
        retryable = retryable and not isinstance(exc, JobCancelled)
        line = exc.line if isinstance(exc, DripFeedBroken) else None
        nbytes = exc.nbytes if isinstance(exc, DripFeedBroken | JobCancelled) else None
        if line is not None:
            reason = f"{reason} (stopped at line {line}; restart from there)"

        def fail(session: Session) -> JobState:
            job = jobs.get_job(session, run.job.job_id)
            if job.state is not JobState.RUNNING or job.claimed_by != self.worker:
                return job.state  # an earlier try went through; its answer was lost
            self._check_lease(session, job.machine, self._epochs.get(job.id))
            return jobs.fail(
                session,
                run.job.job_id,
                reason,
                retryable=retryable,
                backoff=self.retry_backoff,
                line=line,
                nbytes=nbytes,
            ).state

        await self._settle(run, None, fail, error=reason)

    async def stop_runs(self, machines: Iterable[str], timeout: float) -> None:
        """Stop the jobs still running on ``machines`` (a fence: a feed held by the control's
        XOFF never reaches its next block check) by closing their links under them, then
        wait (at most ``timeout`` s) for each to come back with where it stopped."""
        names = set(machines)
        runs = [r for r in self.running.values() if r.state.config.name in names]
        if not runs:
            return

        async def close(run: JobRun) -> None:
            with contextlib.suppress(Exception):
                async with asyncio.timeout(timeout):
                    await run.connector.close()

        await asyncio.gather(*(close(run) for run in runs))
        await self.wait_stopped(names, timeout)

    def fence_off(self, machines: Iterable[str]) -> None:
        """The machines' tasks are about to stop (a fence): a drip-feed still running there
        (its link would not close) is recorded as paused at the last line it reported whole,
        as if it had stopped there by itself."""
        names = set(machines)
        for job_id, run in list(self.running.items()):
            if run.state.config.name not in names or run.job.kind is not JobKind.DRIPFEED:
                continue
            line, nbytes = self._lines.get(job_id, (None, 0))
            start = int(run.job.params.get("from_line", 1))
            why = "its link did not close when the lease ran short"
            self._fenced_off(run, DripFeedBroken(why, line or start, nbytes))

    def _fenced_off(self, run: JobRun, exc: Exception) -> None:
        """``run`` stopped because this server's lease could expire: it writes nothing now
        (its database is likely away, and the machine's task is about to stop)."""
        job_id, machine = run.job.job_id, run.state.config.name
        if job_id in self._paused:
            return  # recorded already (by the fence, before the feed itself stopped)
        self._paused.add(job_id)
        if not isinstance(exc, DripFeedBroken):
            # A load is idempotent: whoever holds the machine next queues it again.
            log.warning("job %d on %s stopped: %s", job_id, machine, exc)
            self._epochs.pop(job_id, None)
            run.state.job_id = None
            return
        # Paused at a block boundary: the line is exact here. It is written (fenced) once the
        # database answers, if this server still holds the lease then; a server that took
        # the machine meanwhile ends the job at the last line this one wrote.
        line, nbytes, position, stopped_at = exc.line, exc.nbytes, exc.position, exc.stopped_at
        if position is not None:
            self._owing[job_id] = machine
            run.state.feed_owed = True
            reason = (
                f"paused at line {line}: {self.worker} lost touch with the database and stopped "
                f"driving {machine}; continued from there by the machine's next server"
            )
        else:
            reason = (
                f"paused at line {line}: {self.worker} lost touch with the database and stopped "
                f"driving {machine} (restart from there)"
            )
        log.warning(
            "job %d: drip-feed paused at line %d (%s stopped driving %s)%s",
            job_id,
            line,
            self.worker,
            machine,
            "" if position is not None else "; its exact position is not known",
        )

        def continue_it(session: Session) -> None:
            # The fenced feed's word on where it stopped: the continuation at the head of the
            # queue (whoever holds the machine runs it), or, without an exact position, the
            # job left for an operator. Either way its next server stops waiting for it.
            if position is not None:
                jobs.resume(
                    session,
                    job_id,
                    actor=self.worker,
                    offset=position.offset,
                    written=position.written,
                    line=line,
                )
                return
            job = jobs.get_job(session, job_id)
            if jobs.AWAITING_POSITION in job.params:
                job.params = {k: v for k, v in job.params.items() if k != jobs.AWAITING_POSITION}

        def correct(session: Session) -> JobState:
            # Another server took the machine meanwhile and ended the job at the last line
            # this one managed to write down (it writes every half second, and not at all
            # while the database is silent): the control has more, up to `line`. A restart
            # from the older line would run those blocks twice.
            job = jobs.get_job(session, job_id, lock=True)  # one writer: a take-over locks it
            if job.state is JobState.RUNNING and job.claimed_by == self.worker:
                # the lease went before its new server took the job over: ended here, at
                # the exact line (that server then finds nothing to take over)
                ended = jobs.fail(
                    session, job_id, reason, retryable=False, line=line, nbytes=nbytes
                )
                continue_it(session)
                return ended.state
            if job.state is not JobState.INTERRUPTED:
                return job.state
            awaited = jobs.AWAITING_POSITION in job.params
            recorded = job.line
            if (recorded or 0) < line:
                job.line, job.bytes_done = line, nbytes
                job.error = f"{reason}; it had been recorded at line {recorded}"
            # Written even when the line was right: the row says when this server wrote its
            # last byte to the machine at the latest (its clock), which is what shows that it
            # stopped before the next server took the machine.
            audit.record(
                session,
                self.worker,
                "job.paused",
                machine=machine,
                job_id=job_id,
                result=job.state.value,
                nbytes=nbytes,
                line=line,
                recorded=recorded,
                stopped_at=None if stopped_at is None else stopped_at.isoformat(),
            )
            if awaited:
                continue_it(session)
            return job.state

        def pause(session: Session) -> JobState:
            job = jobs.get_job(session, job_id)
            if job.state is not JobState.RUNNING or job.claimed_by != self.worker:
                return correct(session)  # ended by the machine's next server meanwhile
            self._check_lease(session, machine, self._epochs.get(job_id))
            ended = jobs.fail(session, job_id, reason, retryable=False, line=line, nbytes=nbytes)
            if position is not None:
                continue_it(session)  # this server runs it itself once it serves again
            return ended.state

        self._settle_later(run, None, pause, {"error": reason}, or_else=correct)

    def _finish(self, session: Session, run: JobRun, outcome: dict[str, Any]) -> JobState:
        def ours(job: Job) -> bool:
            # not ended by an earlier try whose answer was lost, nor a later run of the job
            return (
                job.state is JobState.RUNNING
                and job.claimed_by == self.worker
                and (not run.job.attempt or job.attempts == run.job.attempt)
            )

        job = jobs.get_job(session, run.job.job_id)
        if not ours(job):
            return job.state
        self._check_lease(session, job.machine, self._epochs.get(job.id))
        # Read again locked (after the lease: the order a take-over locks them in): a write
        # of this run still on its way (a fence cut the wait for it) and a later run of the
        # same job (this server took its machine back and claimed it again) must not both
        # read it running and both end it (seen under load: two "done" rows for one load).
        job = jobs.get_job(session, run.job.job_id, lock=True)
        if not ours(job):
            return job.state
        return jobs.finish(session, run.job.job_id, **outcome).state

    async def _settle(
        self,
        run: JobRun,
        label: JobState | None,
        write: Callable[[Session], JobState],
        **extra: Any,
    ) -> None:
        """Record how ``run`` ended. While the database is away the machine keeps the job
        (``state.job_id``: no new claim) and its task keeps polling; the write goes on in the
        background until it goes through."""
        state, job_id = run.state, run.job.job_id
        what = f"recording the end of job {job_id}"
        # The usual case answers at once; the machine's task waits for it, but never longer
        # than SETTLE_WAIT: a database gone silent must not stop the machine's polling.
        attempt = asyncio.ensure_future(asyncio.to_thread(self._transaction, write))
        attempt.add_done_callback(_retrieved)  # whoever waits for it may be gone
        done, _ = await asyncio.wait({attempt}, timeout=SETTLE_WAIT)
        if not done:
            self._trouble(what, TimeoutError(f"no answer within {SETTLE_WAIT:.0f} s"))
            self._settle_later(run, label, write, extra, first=attempt)
            return
        try:
            ended = attempt.result()
        except LeaseLost as exc:
            # Another server has the machine now and ends the job itself (a load queued
            # again, a drip-feed interrupted): this server writes nothing.
            log.warning("job %d: %s; its end is left to that server", job_id, exc)
            self._epochs.pop(job_id, None)
            state.job_id = None
            return
        except Exception as exc:
            if not database_down(exc):
                # Not the database's absence (the row gone, a bug): nothing to wait for, and
                # the machine's link is not to blame.
                log.exception("%s failed", what)
                state.job_id = None
                return
            self._trouble(what, exc)
            self._settle_later(run, label, write, extra)
            return
        self.database_error = ""
        self._epochs.pop(job_id, None)
        self._ended(run, label or ended, **extra)
        state.job_id = None
        # the job no longer speaks for the machine: the card shows the control's own word
        # again at once, not the drip-feed's "running" until a poll happens to change it
        self.machines.publish(state)

    def _settle_later(
        self,
        run: JobRun,
        label: JobState | None,
        write: Callable[[Session], JobState],
        extra: Mapping[str, Any],
        first: asyncio.Future[JobState] | None = None,
        or_else: Callable[[Session], JobState] | None = None,
    ) -> None:
        """Write ``run``'s end in the background, retrying until the database takes it. The
        machine keeps the job meanwhile (``state.job_id``: no new claim) while its task goes
        on polling; no sweep or take-over hands the job back (``_unsettled``). ``first``: an
        attempt still under way, waited for before trying again; ``or_else``: written instead
        when another server has taken the machine over meanwhile."""
        state, job_id = run.state, run.job.job_id
        what = f"recording the end of job {job_id}"
        self._unsettled.add(job_id)

        async def write_it() -> None:
            try:
                ended: JobState | None = None
                if first is not None:
                    try:
                        ended = await first
                    except Exception as exc:
                        if isinstance(exc, LeaseLost) or not database_down(exc):
                            raise
                if ended is None:
                    ended = await self._durably(what, write)
            except LeaseLost as exc:
                log.warning("job %d: %s; its end is left to that server", job_id, exc)
                ended = None  # that server says how it ended
                if or_else is not None:
                    with contextlib.suppress(Exception):
                        ended = await self._durably(what, or_else)
            except Exception:
                log.exception("%s failed", what)
                ended = None  # not known here: the job's row says it
            finally:
                self._unsettled.discard(job_id)
                self._epochs.pop(job_id, None)
                self._paused.discard(job_id)
                self._owing.pop(job_id, None)
            outcome = label or ended
            if outcome is not None:
                self._ended(run, outcome, **extra)
            if state.job_id == job_id:
                state.job_id = None
                state.job_progress = (0, None)
            self.machines.wake(state.config.name)

        task = asyncio.create_task(write_it(), name=f"settle-{job_id}")
        self._settling.add(task)
        task.add_done_callback(self._settling.discard)

    # -- cancels ----------------------------------------------------------------------------

    def cancel_seen(self, job_id: int) -> bool:
        """True while job ``job_id`` runs here and its cancel has been read from its row."""
        run = self.running.get(job_id)
        return run is not None and run.cancel_requested

    def _cancel_flag(self, job_id: int) -> bool:
        with self._reads() as session:
            flag = session.scalar(select(Job.cancel_requested).where(Job.id == job_id))
            if flag is None:
                raise NotFound(f"no job {job_id}")
            return bool(flag)

    async def _cancel_requested(self, job_id: int) -> bool:
        """The job's cancel flag now (False while the database is away: the job goes on)."""
        try:
            return await asyncio.to_thread(self._cancel_flag, job_id)
        except Exception as exc:
            if not database_down(exc):
                raise
            return False

    async def _watch_cancel(self, run: JobRun) -> None:
        """Mirror the job's cancel flag into ``run`` while it runs; record a drip-feed's line
        as it goes (a server that takes the machine over ends the job there)."""
        noted: tuple[int | None, int] | None = None
        while not run.cancel_requested:
            await asyncio.sleep(self.cancel_poll)
            with contextlib.suppress(NotFound):
                run.cancel_requested = await self._cancel_requested(run.job.job_id)
            reached = self._lines.get(run.job.job_id)
            if reached is not None and reached != noted:
                noted = reached
                with contextlib.suppress(LeaseLost, NotFound):
                    await self._note_progress(run, reached)

    async def _note_progress(self, run: JobRun, reached: tuple[int | None, int]) -> None:
        job_id, machine = run.job.job_id, run.state.config.name

        def note(session: Session) -> None:
            self._check_lease(session, machine, self._epochs.get(job_id))
            jobs.note_progress(session, job_id, line=reached[0], nbytes=reached[1])

        try:
            await asyncio.to_thread(self._transaction, note)
        except Exception as exc:
            if not database_down(exc):
                raise
            # the next line is noted once the database answers

    async def wait_stopped(self, machines: Iterable[str], timeout: float) -> None:
        """Wait (at most ``timeout`` s) until no job of ``machines`` runs here any more: a
        fenced drip-feed stops at its next block boundary by itself."""
        names = set(machines)
        end = asyncio.get_running_loop().time() + timeout
        while any(run.state.config.name in names for run in self.running.values()):
            if asyncio.get_running_loop().time() >= end:
                return
            await asyncio.sleep(0.02)

    @property
    def waiting_writes(self) -> int:
        """Job ends this runner holds until the database takes them."""
        return len(self._unsettled)

    def busy(self, machine: str) -> bool:
        """True while a job of ``machine`` is being claimed or runs here."""
        state = self.machines.get(machine)
        return machine in self._claiming or (state is not None and state.job_id is not None)

    def cancel_now(self, job_id: int) -> None:
        """A cancel of job ``job_id`` was committed (a notice from any server): a job running
        here stops at its next safe point without waiting for the next read of its row."""
        run = self.running.get(job_id)
        if run is not None:
            run.cancel_requested = True

    # -- several servers --------------------------------------------------------------------

    def _check_lease(self, session: Session, machine: str, epoch: int | None) -> None:
        """Raise :class:`LeaseLost` unless this server still holds ``machine`` at ``epoch``
        (nothing to check for a single server)."""
        if self.fence is None:
            return
        if epoch is None or not holds(session, machine, self.worker, epoch, self.fence.lock_limit):
            raise LeaseLost(f"{self.worker} no longer holds the lease of {machine}")

    async def take_over(self, epochs: Mapping[str, int]) -> None:
        """This server has just taken these machines' leases (machine -> epoch): end the
        jobs their previous servers left running there (:func:`jobs.take_over`), in one
        transaction, before the machines' tasks start. Raises if the database is away."""
        # the jobs running here, and those whose end is on its way to the database (a fenced
        # drip-feed's exact line, a finished load's "done"): never handed back
        keep = set(self.running) | self._unsettled

        waits: dict[str, tuple[int, str]] = {}  # machine -> (drip-feed, its server)
        owed: set[str] = set()  # machines with a continuation queued already

        def adopt(session: Session) -> list[JobFinished]:
            out: list[JobFinished] = []
            waits.clear()
            # one query for all: usually few of them have a job left running
            busy = jobs.machines_running(session, list(epochs))
            for machine, epoch in sorted(epochs.items()):
                if machine not in busy or not holds(session, machine, self.worker, epoch):
                    continue
                for job in jobs.take_over(session, machine, self.worker, keep):
                    was = job.params.get(jobs.AWAITING_POSITION)
                    if was is not None:
                        waits[machine] = (job.id, str(was))
                    version = job.version
                    out.append(
                        JobFinished(
                            job.id,
                            machine,
                            job.kind,
                            version.program.name if version is not None else None,
                            version.number if version is not None else None,
                            outcome=job.state,
                            error=job.error,
                        )
                    )
            # After the take-overs: a continuation an old server queued before they locked
            # its job (ending the job itself: it found the lease gone) is seen here; one it
            # queues after them finds its job awaiting the position, which is waited for.
            owed.clear()
            owed.update(jobs.continuations_queued(session, list(epochs)))
            return out

        events = await asyncio.to_thread(self._transaction, adopt)
        for machine in owed:
            state = self.machines.get(machine)
            if state is not None:
                state.feed_owed = True  # its task starts after this: the rest first
        until = time.monotonic() + self.resume_wait
        for machine, (job_id, was) in waits.items():
            state = self.machines.get(machine)
            if state is not None and self.resume_wait > 0:
                # its task starts after this: it waits, silent, for the exact position
                state.awaiting_position = (job_id, was, until)
        for event in events:
            log.warning("job %d of %s taken over: %s", event.job_id, event.machine, event.outcome)
            self.machines.bus.publish(event)
            if event.outcome is JobState.QUEUED:
                fields = (event.job_id, event.machine, event.job_kind, event.program)
                self.machines.bus.publish(JobQueued(*fields, event.version, by=self.worker))

    async def await_position(self, state: MachineState) -> None:
        """Wait, with the machine's port silent, until the drip-feed a take-over ended there
        has its old server's word on where it stopped (a continuation queued, or no position
        known), at most ``resume_wait`` seconds; sooner when the database shows that server
        gone (started again, or its process dead on this host). A control left in DNC mode
        would take a status poll or a listener's NAK as program input."""
        waiting = state.awaiting_position
        if waiting is None:
            return
        job_id, was, until = waiting
        name = state.config.name
        log.info(
            "%s: waiting up to %.0f s for %s's position of job %d",
            name,
            max(0.0, until - time.monotonic()),
            was,
            job_id,
        )
        why = ""
        while not why:
            left = until - time.monotonic()
            if left <= 0:
                why = f"no word from {was} within {self.resume_wait:g} s"
                break
            try:
                why = await asyncio.to_thread(self._position_news, job_id, was)
            except Exception as exc:
                if not database_down(exc):
                    raise
                self._trouble(f"waiting for the position of job {job_id}", exc)
            if not why:
                # a continuation queued by any server wakes the machine at once
                with contextlib.suppress(TimeoutError):
                    async with asyncio.timeout(min(POSITION_POLL, max(0.0, left))):
                        await state.wake.wait()
        state.awaiting_position = None
        state.feed_owed = True  # until the database shows no continuation queued here
        state.wake.set()  # the queue at once: a continuation is at its head
        log.info("%s: done waiting for job %d's position: %s", name, job_id, why)

    def _position_news(self, job_id: int, was: str) -> str:
        """Why the wait for job ``job_id``'s position is over, or "" to go on waiting."""
        with self._reads() as session:
            if jobs.position_said(session, job_id):
                return f"{was} said where it stopped"
            finished = session.scalar(select(Job.finished).where(Job.id == job_id))
            row = session.get(ClusterServer, was)
            if row is None:
                return f"{was} left the cluster"
            if finished is not None and row.started > finished:
                return f"{was} started again: it knows no position"
            if row.host == socket.gethostname()[:255] and not _alive(row.pid):
                return f"{was}'s process is gone"
            return ""

    async def owes_feed(self, state: MachineState) -> bool:
        """True while ``state``'s control may wait in DNC mode for the rest of a fenced
        drip-feed: this server is still writing that feed's position, or its continuation
        is queued there. The machine's task then runs the queue and nothing else: a claim
        can miss the continuation (a lease not confirmed at that moment), and a status poll
        or a listener's NAK in between would reach the control as program input."""
        if not state.feed_owed:
            return False
        name = state.config.name
        if name in self._owing.values():
            return True
        try:
            queued = await asyncio.to_thread(self._continuation_queued, name)
        except Exception as exc:
            if not database_down(exc):
                raise
            self._trouble(f"looking for the continuation of a feed on {name}", exc)
            return True  # not known: silent until the database answers
        if not queued:
            state.feed_owed = False
        return queued

    def _continuation_queued(self, machine: str) -> bool:
        with self._reads() as session:
            return machine in jobs.continuations_queued(session, [machine])

    # -- events ---------------------------------------------------------------------------

    def _progress(self, job: Claimed, machine: str, progress: TransferProgress) -> None:
        # From the transfer's thread too: a drip-feed's line is kept for the cancel watch,
        # which records it in the job's row (what a taking-over server reports).
        if job.kind is JobKind.DRIPFEED:
            self._lines[job.job_id] = (progress.line, progress.bytes_done)
        # Called after each block written whole and before the next: a server whose lease
        # could expire soon writes not one block more, whatever its event loop and its
        # database are doing (the check reads the process's clock only).
        self._still_driving(job, machine)
        self.machines.bus.publish(JobProgress.of(*_fields(job, machine), progress))

    def _still_driving(self, job: Claimed, machine: str) -> None:
        """Raise :class:`Fenced` once this server may no longer drive ``machine`` for ``job``
        (from any thread: a transfer's between its writes, a held drip-feed's as it waits)."""
        if self.fence is not None and self.fence.epoch(machine) != self._epochs.get(job.job_id):
            raise Fenced(
                f"{self.worker} stopped driving {machine}: its lease could not be renewed in time"
            )

    def _ended(self, run: JobRun, outcome: JobState, error: str = "") -> None:
        fields = _fields(run.job, run.state.config.name)
        self.machines.bus.publish(JobFinished(*fields, outcome=outcome, error=error))


def _alive(pid: int) -> bool:
    """Whether process ``pid`` of this host exists (a permission refusal: it does)."""
    if pid <= 0:
        return True  # not known: keep waiting
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:
        return True
    return True


def _retrieved(future: asyncio.Future[Any]) -> None:
    """Mark ``future``'s error as seen (its waiter handles it, or has been cancelled)."""
    if not future.cancelled():
        future.exception()


def _fields(job: Claimed, machine: str) -> tuple[int, str, JobKind, str | None, int | None]:
    """What every event of ``job`` carries: id, machine, kind, program, version."""
    return job.job_id, machine, job.kind, job.program, job.version
