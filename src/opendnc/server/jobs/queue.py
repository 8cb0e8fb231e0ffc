"""The durable job queue: the only code that moves a job between states.

Jobs are rows, so a queue survives restarts. Each machine runs one job at a time, in queue
order (``position``), which people can change. Every state change writes its audit row in the
same transaction.

Claiming: a worker first locks its machine's row, then takes the first due queued job. On
PostgreSQL both locks are ``FOR UPDATE SKIP LOCKED``, so several servers sharing one database
never run two jobs on one port or one job twice. SQLite has no row locks: there every
transaction starts with ``BEGIN IMMEDIATE`` (:mod:`opendnc.server.store.db`), which takes the
database's write lock, so claims are serialised across threads and processes alike.

Retries: a program load is idempotent, so a failed send is queued again with exponential
backoff until ``max_attempts``. A drip-feed is not: after a break the machine has run an unknown
part of the program, so it ends *interrupted* and a person restarts it from a line.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from datetime import datetime, timedelta
from typing import Any

from sqlalchemy import case, func, or_, select
from sqlalchemy.dialects.postgresql import insert as pg_insert
from sqlalchemy.orm import Session, selectinload
from sqlalchemy.orm.interfaces import LoaderOption

from opendnc.errors import InputError
from opendnc.server.config.shop import MachineConfig
from opendnc.server.core.errors import Conflict, NotFound
from opendnc.server.library import versions as library
from opendnc.server.store import audit
from opendnc.server.store.models import (
    Job,
    JobKind,
    JobState,
    Machine,
    ProgramVersion,
    utcnow,
)
from opendnc.server.store.notify import Topic, notify

__all__ = [
    "AWAITING_POSITION",
    "LOADS",
    "RESUME",
    "RESUME_OF",
    "TAKEN_OVER_FROM",
    "NotReleased",
    "cancel",
    "claim",
    "continuations_queued",
    "enqueue",
    "fail",
    "finish",
    "get_job",
    "interrupt",
    "last_finished",
    "list_jobs",
    "machines_running",
    "machines_with_due_jobs",
    "move",
    "note_progress",
    "position_said",
    "queue_lengths",
    "recover",
    "resume",
    "retry",
    "sync_machines",
    "take_over",
    "version_to_send",
]

# Jobs that carry a program version to the control. Which versions a machine takes (its
# ``released_only`` policy, the drip-feed opt-in) is decided by the actions layer
# (opendnc.server.actions.policy), the one place every caller's request passes through.
PROGRAM_JOBS = (JobKind.SEND, JobKind.DRIPFEED, JobKind.PUT_FILE)

LOADS = (JobKind.SEND, JobKind.REPORT, JobKind.PUT_FILE)
"""Jobs that write a file to the control: what a take-over checks at the control before
writing again (docs/server.md#jobs-in-a-cluster)."""

TAKEN_OVER_FROM = "taken_over_from"
"""The ``params`` key of a load queued again by a take-over: the server that had it running."""

RESUME = "resume"
"""The ``params`` key of a drip-feed's continuation: ``{"offset": file offset of the line it
starts at, "written": hex of that line's wire bytes the control has}``
(:class:`opendnc.haas.dnc_engine.FeedPosition`)."""
RESUME_OF = "resume_of"
"""The ``params`` key of a continuation: the fenced drip-feed it continues."""
AWAITING_POSITION = "awaiting_position"
"""The ``params`` key of a drip-feed a take-over ended: the server that was feeding it, whose
exact position the machine's new server waits for (removed once that server has said it)."""

DEFAULT_ATTEMPTS = {
    JobKind.SEND: 3,
    JobKind.RECEIVE: 1,
    JobKind.BACKUP: 2,
    JobKind.DRIPFEED: 1,
    JobKind.DELETE: 2,
    JobKind.REPORT: 3,
    JobKind.PUT_FILE: 2,
}


def sync_machines(session: Session, machines: Iterable[MachineConfig]) -> None:
    """Make the ``machines`` table match the configuration (rows are never deleted: jobs
    and audit rows keep pointing at machines that left the configuration)."""
    configs = list(machines)
    if session.get_bind().dialect.name == "postgresql" and configs:
        # Several servers of a cluster may start at once: one statement that inserts or
        # updates each row, so the second never fails on the first's new row.
        statement = pg_insert(Machine).values(
            [{"name": c.name, "kind": c.kind, "released_only": c.released_only} for c in configs]
        )
        session.execute(
            statement.on_conflict_do_update(
                index_elements=[Machine.name],
                set_={
                    "kind": statement.excluded.kind,
                    "released_only": statement.excluded.released_only,
                },
            )
        )
        return
    existing = {m.name: m for m in session.scalars(select(Machine))}
    for config in configs:
        row = existing.get(config.name)
        if row is None:
            session.add(
                Machine(name=config.name, kind=config.kind, released_only=config.released_only)
            )
        else:
            row.kind = config.kind
            row.released_only = config.released_only
    session.flush()


def _machine(session: Session, name: str) -> Machine:
    row = session.scalar(select(Machine).where(Machine.name == name))
    if row is None:
        raise NotFound(f"no machine named {name!r}")
    return row


def _next_position(session: Session, machine: str) -> float:
    last = session.scalar(
        select(Job.position)
        .where(Job.machine == machine, Job.state == JobState.QUEUED)
        .order_by(Job.position.desc())
        .limit(1)
    )
    return (last or 0.0) + 1.0


def enqueue(
    session: Session,
    kind: JobKind,
    machine: str,
    *,
    actor: str,
    version: ProgramVersion | None = None,
    params: dict[str, Any] | None = None,
    max_attempts: int | None = None,
    not_before: datetime | None = None,
) -> Job:
    """Queue a job at the end of ``machine``'s queue (not run before ``not_before``)."""
    _machine(session, machine)
    if kind in PROGRAM_JOBS and version is None:
        raise InputError(f"a {kind.value} job needs a program version")
    job = Job(
        kind=kind,
        machine=machine,
        state=JobState.QUEUED,
        position=_next_position(session, machine),
        version=version,
        params=dict(params or {}),
        max_attempts=max_attempts or DEFAULT_ATTEMPTS[kind],
        created_by=actor,
        not_before=not_before,
    )
    session.add(job)
    session.flush()
    audit.record(
        session,
        actor,
        "job.queue",
        machine=machine,
        job_id=job.id,
        program=version.program.name if version else None,
        sha256=version.sha256 if version else None,
        kind=kind.value,
    )
    notify(session, Topic.JOB, machine)  # the server serving it claims it at once
    return job


class NotReleased(Conflict):
    """A program asked for without a version number that has no released version (409)."""


def version_to_send(session: Session, name: str, number: int | None) -> ProgramVersion:
    """Version ``number`` of ``name``, or the released one without it (none released:
    :class:`NotReleased`).

    What a send, a drip-feed, a file put or a control's request means by a program, wherever
    it is asked: :func:`opendnc.server.actions.policy.authorize` resolves it so, and nothing
    else in the server picks a version to put on a machine."""
    if number is None:
        version = library.released_version(session, name)
        if version is None:
            raise NotReleased(f"program {name!r} has no released version; name one")
        return version
    return library.get_version(session, name, number)


def claim(session: Session, machine: str, worker: str) -> Job | None:
    """Take the next due job of ``machine`` for ``worker``, or None (see module docstring)."""
    locked = session.scalar(
        select(Machine).where(Machine.name == machine).with_for_update(skip_locked=True)
    )
    if locked is None:
        return None
    busy = session.scalar(
        select(Job.id).where(Job.machine == machine, Job.state == JobState.RUNNING).limit(1)
    )
    if busy is not None:
        return None
    now = utcnow()
    job = session.scalar(
        select(Job)
        .where(
            Job.machine == machine,
            Job.state == JobState.QUEUED,
            or_(Job.not_before.is_(None), Job.not_before <= now),
        )
        .order_by(Job.position, Job.id)
        .limit(1)
        .with_for_update(skip_locked=True)
        .options(_with_program())
    )
    if job is None:
        return None
    job.state = JobState.RUNNING
    job.claimed_by = worker
    job.started = now
    job.attempts += 1
    job.error = ""
    audit.record(session, worker, "job.start", machine=machine, job_id=job.id, attempt=job.attempts)
    return job


def _running(session: Session, job_id: int) -> Job:
    job = get_job(session, job_id, lock=True)  # two enders never both see it running
    if job.state is not JobState.RUNNING:
        raise Conflict(f"job {job_id} is {job.state.value}, not running")
    return job


def _program_fields(job: Job) -> dict[str, Any]:
    """The program a job carried, as its audit rows name it."""
    if job.version is None:
        return {}
    return {"program": job.version.program.name, "sha256": job.version.sha256}


def _record_ending(session: Session, job: Job, **detail: Any) -> None:
    """The audit row of a run's ending (done, a retry, failed, interrupted): its action is the
    job's kind, its actor the server that ran it; it names the program the job carried."""
    audit.record(
        session,
        job.claimed_by or "server",
        f"job.{job.kind.value}",
        machine=job.machine,
        job_id=job.id,
        **detail,
        **_program_fields(job),
    )


def finish(session: Session, job_id: int, *, nbytes: int | None = None, **detail: Any) -> Job:
    """Mark a running job done."""
    job = _running(session, job_id)
    job.state = JobState.DONE
    job.finished = utcnow()
    if nbytes is not None:
        job.bytes_done = nbytes
    _record_ending(session, job, nbytes=nbytes, by=job.created_by, **detail)
    return job


def fail(
    session: Session,
    job_id: int,
    error: str,
    *,
    retryable: bool = True,
    backoff: float = 2.0,
    line: int | None = None,
    nbytes: int | None = None,
) -> Job:
    """A running job failed: queue it again after a backoff while attempts remain.

    ``line`` is the program line a drip-feed had reached (where a restart would pick up),
    ``nbytes`` the bytes it had fed by then: what its history row shows.
    """
    job = _running(session, job_id)
    job.error = error
    if line is not None:
        job.line = line
    if nbytes is not None:
        job.bytes_done = nbytes
    again = retryable and job.kind is not JobKind.DRIPFEED and job.attempts < job.max_attempts
    again = again and not job.cancel_requested
    if again:
        job.state = JobState.QUEUED
        job.not_before = utcnow() + timedelta(seconds=min(backoff * 2 ** (job.attempts - 1), 300))
    elif job.kind is JobKind.DRIPFEED:
        job.state = JobState.INTERRUPTED
        job.finished = utcnow()
    else:
        job.state = JobState.CANCELLED if job.cancel_requested else JobState.FAILED
        job.finished = utcnow()
    _record_ending(
        session,
        job,
        result="retry" if again else job.state.value,
        error=error,
        attempt=job.attempts,
        line=line,
        nbytes=nbytes,
    )
    return job


def interrupt(session: Session, job_id: int, reason: str) -> Job:
    """Mark a running job interrupted (its outcome on the machine is unknown)."""
    job = _running(session, job_id)
    job.state = JobState.INTERRUPTED
    job.error = reason
    job.finished = utcnow()
    _record_ending(session, job, result="interrupted", error=reason)
    return job


def recover(session: Session, worker: str) -> list[Job]:
    """At start: every job this server left running becomes interrupted, with the reason."""
    jobs = session.scalars(
        select(Job)
        .where(Job.state == JobState.RUNNING, Job.claimed_by == worker)
        .options(_with_program())
    ).all()
    for job in jobs:
        interrupt(session, job.id, "the server stopped while this job ran")
    return list(jobs)


def take_over(session: Session, machine: str, server: str, keep: Iterable[int] = ()) -> list[Job]:
    """``server`` has just taken ``machine``'s lease: end, exactly once, every job the
    database says runs there but no task of ``server`` runs (``keep``: the ones it does).

    Their server died or lost the machine mid-job. A drip-feed ends interrupted at the last
    line its server recorded (the machine ran an unknown part beyond it; a person restarts it
    from a line); every other job is queued again at its place, without a backoff: a read or
    a backup is harmless to repeat, and a program load is marked (``params``
    :data:`TAKEN_OVER_FROM`) so that its next run first asks the control whether it already
    holds those bytes (the old server may have finished the transfer without recording it)
    and ends done without sending them again if so (:mod:`opendnc.server.jobs.executors`). The
    rows are locked, so a job's old server finishing it at the same moment (it cannot: its
    lease check fails) or a second taker never ends it twice. The audit row names both
    servers.
    """
    kept = set(keep)
    found = session.scalars(
        select(Job)
        .where(Job.machine == machine, Job.state == JobState.RUNNING)
        .with_for_update()
        .options(_with_program())
    ).all()
    ended: list[Job] = []
    for job in found:
        if job.id in kept:
            continue
        was = job.claimed_by or "a server"
        if job.kind is JobKind.DRIPFEED:
            job.state = JobState.INTERRUPTED
            job.finished = utcnow()
            where = f" at line {job.line}" if job.line else ""
            job.error = f"{was} stopped while feeding{where}; {server} took the machine over"
            result = "interrupted"
            # The line noted every half second is a lower bound: never fed from. A fenced
            # server knows its exact position and writes it once it reaches the database;
            # the machine's new server waits for that word (a new dict: see below).
            job.params = {**job.params, AWAITING_POSITION: was}
        else:
            job.state = JobState.QUEUED
            job.not_before = None
            result = "queued again"
            if job.kind in LOADS:
                # a new dict: the JSON column sees a changed value, not a changed object
                job.params = {**job.params, TAKEN_OVER_FROM: was}
                job.error = (
                    f"{was} stopped while this job ran; {server} queued it again, to ask the "
                    "control first whether it already has the program"
                )
            else:
                job.error = f"{was} stopped while this job ran; {server} queued it again"
        audit.record(
            session,
            server,
            "job.takeover",
            machine=machine,
            job_id=job.id,
            result=result,
            previous=was,
            attempt=job.attempts,
            line=job.line if job.kind is JobKind.DRIPFEED else None,
            **_program_fields(job),
        )
        ended.append(job)
    return ended


def resume(
    session: Session,
    job_id: int,
    *,
    actor: str,
    offset: int,
    written: bytes,
    line: int,
) -> Job:
    """Queue the continuation of drip-feed ``job_id`` (ended: a fence stopped it) at the head
    of its machine's queue: the rest of the line at file ``offset`` (``written``: its bytes
    the control already has) and the lines after, no leader, no ``%``. ``line`` is the
    program line it starts in. Audited ``job.resume``; the old job no longer awaits its
    position (:data:`AWAITING_POSITION`)."""
    old = get_job(session, job_id)
    if old.kind is not JobKind.DRIPFEED or old.version is None:
        raise Conflict(f"job {job_id} is no drip-feed: nothing to continue")
    if old.state in (JobState.QUEUED, JobState.RUNNING):
        raise Conflict(f"job {job_id} is {old.state.value}: nothing to continue yet")
    params = {k: v for k, v in old.params.items() if k not in (AWAITING_POSITION, TAKEN_OVER_FROM)}
    old.params = params  # a new dict: the JSON column sees a changed value
    params = {
        **params,
        "from_line": line,
        RESUME: {"offset": offset, "written": written.hex()},
        RESUME_OF: job_id,
    }
    first = session.scalar(
        select(func.min(Job.position)).where(
            Job.machine == old.machine, Job.state == JobState.QUEUED
        )
    )
    job = Job(
        kind=JobKind.DRIPFEED,
        machine=old.machine,
        state=JobState.QUEUED,
        position=(first if first is not None else 1.0) - 1.0,  # before every queued job
        version=old.version,
        params=params,
        max_attempts=1,
        created_by=actor,
    )
    session.add(job)
    session.flush()
    audit.record(
        session,
        actor,
        "job.resume",
        machine=old.machine,
        job_id=job.id,
        resume_of=job_id,
        line=line,
        offset=offset,
        written=len(written),
        **_program_fields(old),
    )
    notify(session, Topic.JOB, old.machine)
    return job


def position_said(session: Session, job_id: int) -> bool:
    """True once drip-feed ``job_id`` no longer awaits its old server's exact position
    (written, or said not to be known, or never awaited)."""
    params = session.scalar(select(Job.params).where(Job.id == job_id))
    return params is None or AWAITING_POSITION not in params


def continuations_queued(session: Session, machines: Sequence[str]) -> set[str]:
    """Which of ``machines`` have a drip-feed's continuation (:data:`RESUME_OF`) queued."""
    if not machines:
        return set()
    rows = session.execute(
        select(Job.machine, Job.params).where(
            Job.machine.in_(machines),
            Job.state == JobState.QUEUED,
            Job.kind == JobKind.DRIPFEED,
        )
    )
    # the key is looked for here, not in SQL: JSON operators differ between the two
    # databases, and a machine has few queued drip-feeds
    return {machine for machine, params in rows if params and RESUME_OF in params}


def machines_running(session: Session, machines: Sequence[str]) -> set[str]:
    """Which of ``machines`` have a job running (by any server)."""
    if not machines:
        return set()
    stmt = select(Job.machine).where(Job.machine.in_(machines), Job.state == JobState.RUNNING)
    return set(session.scalars(stmt.distinct()))


def note_progress(session: Session, job_id: int, *, line: int | None, nbytes: int) -> None:
    """Record how far a running job got (a drip-feed's line): what a server that takes the
    machine over reports if this one dies."""
    # The row locked first: a note read as running just before the job's end committed
    # would otherwise write its older count over the end's (PostgreSQL, READ COMMITTED).
    job = session.get(Job, job_id, with_for_update=True)
    if job is not None and job.state is JobState.RUNNING:
        if line is not None:
            job.line = line
        job.bytes_done = nbytes


def machines_with_due_jobs(session: Session) -> list[str]:
    """Machines that have a queued job whose time has come."""
    now = utcnow()
    stmt = (
        select(Job.machine)
        .where(Job.state == JobState.QUEUED, or_(Job.not_before.is_(None), Job.not_before <= now))
        .distinct()
    )
    return list(session.scalars(stmt))


def queue_lengths(session: Session) -> dict[str, int]:
    """Queued jobs per machine (machines with none are left out)."""
    stmt = (
        select(Job.machine, func.count(Job.id))
        .where(Job.state == JobState.QUEUED)
        .group_by(Job.machine)
    )
    return {machine: int(count) for machine, count in session.execute(stmt)}


def last_finished(session: Session, machines: Iterable[str] | None = None) -> dict[str, Job]:
    """Each machine's most recently finished job (done, failed, cancelled or interrupted),
    its version and program loaded; ``machines`` limits the machines asked about."""
    ended = [JobState.DONE, JobState.FAILED, JobState.CANCELLED, JobState.INTERRUPTED]
    newest = select(func.max(Job.id)).where(Job.state.in_(ended)).group_by(Job.machine)
    if machines is not None:
        newest = newest.where(Job.machine.in_(list(machines)))
    stmt = select(Job).where(Job.id.in_(newest)).options(_with_program())
    return {job.machine: job for job in session.scalars(stmt)}


def _with_program() -> LoaderOption:
    # a job's version and its program come with the job (relationships never load lazily)
    return selectinload(Job.version).selectinload(ProgramVersion.program)


def get_job(session: Session, job_id: int, *, lock: bool = False) -> Job:
    """The job ``job_id``; :class:`NotFound` otherwise. ``lock``: its row locked for this
    transaction and read afresh (a check of its state before a write: under PostgreSQL's read
    committed, two writers that both read it running would both end it)."""
    job = session.get(
        Job,
        job_id,
        options=[_with_program()],
        with_for_update=True if lock else None,
        populate_existing=lock,
    )
    if job is None:
        raise NotFound(f"no job {job_id}")
    return job


def list_jobs(
    session: Session,
    *,
    machine: str | None = None,
    states: Iterable[JobState] = (),
    limit: int = 200,
) -> Sequence[Job]:
    """Jobs, queued ones in queue order first, then the rest newest first."""
    stmt = select(Job)
    if machine is not None:
        stmt = stmt.where(Job.machine == machine)
    wanted = list(states)
    if wanted:
        stmt = stmt.where(Job.state.in_(wanted))
    # The queue in its order first; the rest (history) newest first by id: a position only
    # means something while a job waits.
    queued_first = (Job.state == JobState.QUEUED).desc()
    in_queue = case((Job.state == JobState.QUEUED, Job.position), else_=0.0)
    stmt = stmt.order_by(queued_first, in_queue, Job.id.desc()).options(_with_program())
    return session.scalars(stmt.limit(max(1, min(limit, 10_000)))).all()


def cancel(session: Session, job_id: int, *, actor: str) -> Job:
    """Cancel a queued job at once; ask a running one to stop at its next safe point."""
    job = get_job(session, job_id)
    if job.state is JobState.QUEUED:
        job.state = JobState.CANCELLED
        job.finished = utcnow()
    elif job.state is JobState.RUNNING:
        job.cancel_requested = True
        notify(session, Topic.CANCEL, str(job.id))  # whichever server runs it stops it at once
    else:
        raise Conflict(f"job {job_id} is {job.state.value}; nothing to cancel")
    audit.record(session, actor, "job.cancel", machine=job.machine, job_id=job.id)
    return job


def move(session: Session, job_id: int, index: int, *, actor: str) -> Job:
    """Put a queued job at ``index`` (0 = next) in its machine's queue."""
    job = get_job(session, job_id)
    if job.state is not JobState.QUEUED:
        raise Conflict(f"job {job_id} is {job.state.value}; only queued jobs move")
    queue = [
        j
        for j in session.scalars(
            select(Job)
            .where(Job.machine == job.machine, Job.state == JobState.QUEUED)
            .order_by(Job.position, Job.id)
        )
        if j.id != job.id
    ]
    index = max(0, min(index, len(queue)))
    queue.insert(index, job)
    # Renumber the whole (short) queue: simple, and positions never run out of precision.
    for n, item in enumerate(queue, start=1):
        item.position = float(n)
    audit.record(session, actor, "job.move", machine=job.machine, job_id=job.id, index=index)
    notify(session, Topic.JOB, job.machine)
    return job


def retry(session: Session, job_id: int, *, actor: str, from_line: int | None = None) -> Job:
    """Queue a new job doing what a finished, unsuccessful job did.

    A new row keeps the history honest: the old job stays as it ended. A drip-feed restart
    names the line to start from (its preamble restores the modal state).
    """
    old = get_job(session, job_id)
    if old.state not in (JobState.FAILED, JobState.INTERRUPTED, JobState.CANCELLED):
        raise Conflict(
            f"job {job_id} is {old.state.value}; only failed, interrupted or "
            "cancelled jobs are retried"
        )
    params = dict(old.params)
    params.pop(TAKEN_OVER_FROM, None)  # a person asks for a load: it is sent, not first asked
    # a person's restart starts at a line, never at a fenced feed's old position
    for key in (RESUME, RESUME_OF, AWAITING_POSITION):
        params.pop(key, None)
    if from_line is not None:
        if old.kind is not JobKind.DRIPFEED:
            raise InputError("only a drip-feed restarts from a line")
        if from_line < 1:
            raise InputError("from_line counts from 1")
        params["from_line"] = from_line
    params["retry_of"] = old.id
    return enqueue(session, old.kind, old.machine, actor=actor, version=old.version, params=params)
