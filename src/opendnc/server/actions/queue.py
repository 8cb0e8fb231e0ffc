"""Queue actions: queue jobs (send, drip-feed, receive, delete, backup, put a file), list
them, cancel, move and retry. A cancel or a move only changes rows: the machine's runner
reads them at its safe points (:func:`opendnc.server.jobs.queue.cancel_requested`)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from sqlalchemy.orm import Session

from opendnc.errors import InputError
from opendnc.server.actions import policy
from opendnc.server.actions.base import Caller, Services, require
from opendnc.server.actions.models import JobOut, JobRequest
from opendnc.server.core.errors import Conflict
from opendnc.server.jobs import queue as jobs
from opendnc.server.kinds.files import check_path
from opendnc.server.store import audit
from opendnc.server.store.models import JobKind, JobState, ProgramVersion, Role

__all__ = [
    "Queued",
    "Refusal",
    "RefusedEverywhere",
    "cancel_job",
    "create_jobs",
    "get_job",
    "list_jobs",
    "move_job",
    "queue_each",
    "retry_job",
]


@dataclass(frozen=True)
class Refusal:
    """A machine a request to the queue left out, and why (the policy's own words)."""

    machine: str
    reason: str


@dataclass(frozen=True)
class Queued:
    """What a request to many machines did: the jobs queued on the machines that take
    them, and each machine refused with its reason."""

    jobs: list[JobOut]
    refused: list[Refusal]


def create_jobs(
    svc: Services,
    who: Caller,
    order: JobRequest,
    *,
    extra: dict[str, str | int | bool] | None = None,
) -> list[JobOut]:
    """Queue one job per machine: all of them, or (any refusal) none (the actions' own
    requests: a take-back, the file browser, the demo). A send or drip-feed is refused where
    the version's program check finds errors for that machine, unless the order's
    ``override`` gives a reason (programmers; audited per machine). ``extra`` are the
    actions' own parameters (a take-back's ``into_library``), never a request's."""
    return _create(svc, who, order, extra=extra, each=False).jobs


def queue_each(svc: Services, who: Caller, order: JobRequest) -> Queued:
    """Queue one job on each machine that takes it, and name each one that refuses it with
    its reason (its machine's rule, the program check), audited as ``job.refused``: a send
    to four machines of which two fail the check goes to the other two. Refused on every
    machine: :class:`~opendnc.server.core.errors.Conflict` (409) naming each and why, the
    refusals audited all the same. What concerns the request itself (the role, the
    program, the version) refuses it whole, as before."""
    return _create(svc, who, order, each=True)


def _create(
    svc: Services,
    who: Caller,
    order: JobRequest,
    *,
    extra: dict[str, str | int | bool] | None = None,
    each: bool,
) -> Queued:
    kind = order.kind
    program = order.program
    wanted = policy.Wanted(program, order.version) if program is not None else None
    # the role, the override, the version and each machine's check, before the transaction:
    # a dry run may take seconds and takes no lock
    prepared = policy.authorize(
        svc, who, wanted, order.machines, policy.Action.queue(kind), override=order.override
    )
    path = None
    if kind is not JobKind.SEND and kind is not JobKind.DRIPFEED:
        if order.path is None:
            raise InputError(f"a {kind.value} job names a path on the control")
        # a file browser's path stays on the control's drive; other kinds name a file the
        # machine's connector checks (a share-relative name on a Haas)
        path = check_path(order.path) if kind is JobKind.PUT_FILE else order.path
        if "\x00" in path:
            raise InputError("a path holds no NUL character")
    if order.from_line is not None and kind is not JobKind.DRIPFEED:
        raise InputError("only a drip-feed starts from a line")

    refused: dict[str, str] = {}

    def queue(session: Session) -> list[JobOut]:
        decision = prepared.confirm(session)  # the version and each machine, read once
        if not each:
            decision.require_all()
        refused.clear()
        refused.update({v.machine or "": v.reason for v in decision.refused})
        if not decision.allowed:
            raise _NoMachine(refused)
        version = decision.row
        created = []
        for verdict in decision.allowed:
            machine = verdict.machine or ""
            params: dict[str, str | int | bool] = dict(extra or {})
            if path is not None:
                params["path"] = path
            if order.from_line is not None:
                params["from_line"] = order.from_line
            if verdict.overridden and decision.override is not None:
                params["check_override"] = decision.override.why  # a retry of the job keeps it
            job = jobs.enqueue(
                session, kind, machine, actor=who.name, version=version, params=params
            )
            created.append(job)
            if verdict.overridden:
                policy.record_override(session, decision, verdict, job_id=job.id)
        _audit_refusals(session, who, kind, version, refused)
        return [JobOut.of(j) for j in created]

    try:
        out = svc.write(queue)
    except _NoMachine as none:
        # nothing queued: the refusals are audited in a transaction of their own
        version_of = None
        if program is not None:
            version_of = (program, order.version)
        left, conflict = none.refused, none.conflict()
        svc.write(lambda s: _audit_refusals(s, who, kind, version_of, left))
        raise conflict from None
    svc.queued(out)
    return Queued(out, [Refusal(m, why) for m, why in refused.items()])


class _NoMachine(Exception):
    """Every machine of a request refused it (the transaction rolls back)."""

    def __init__(self, refused: dict[str, str]) -> None:
        super().__init__("no machine takes it")
        self.refused = dict(refused)

    def conflict(self) -> RefusedEverywhere:
        """409 in the policy's words: one machine's as it said it, several named each."""
        refusals = [Refusal(m, why) for m, why in self.refused.items()]
        if len(refusals) == 1:
            return RefusedEverywhere(refusals[0].reason, refusals)
        said = "; ".join(f"{r.machine}: {r.reason}" for r in refusals)
        return RefusedEverywhere(f"refused on every machine: {said}", refusals)


class RefusedEverywhere(Conflict):
    """A request every machine refused (HTTP 409); ``refused`` names each and why."""

    def __init__(self, message: str, refused: list[Refusal]) -> None:
        super().__init__(message)
        self.refused = refused


def _audit_refusals(
    session: Session,
    who: Caller,
    kind: JobKind,
    version: ProgramVersion | tuple[str, int | None] | None,
    refused: dict[str, str],
) -> None:
    """One ``job.refused`` row per machine left out, with the reason."""
    program: str | None = None
    number: int | None = None
    sha: str | None = None
    if isinstance(version, ProgramVersion):
        program, number, sha = version.program.name, version.number, version.sha256
    elif version is not None:
        program, number = version
    for machine, why in refused.items():
        audit.record(
            session,
            who.name,
            "job.refused",
            machine=machine,
            program=program,
            sha256=sha,
            result="refused",
            to=kind.value,
            version=number,
            error=why,
        )


def _live(svc: Services) -> dict[int, tuple[int, int | None]]:
    return {m.job_id: m.job_progress for m in svc.runner.machines.values() if m.job_id is not None}


def list_jobs(
    svc: Services,
    who: Caller,
    *,
    machine: str | None = None,
    states: Sequence[JobState] = (),
    limit: int = 200,
) -> list[JobOut]:
    """Jobs: the queued ones in queue order first, then the rest newest first (three
    queries, however many jobs)."""
    require(who, Role.VIEWER)
    live = _live(svc)

    def load(session: Session) -> list[JobOut]:
        found = jobs.list_jobs(session, machine=machine, states=states, limit=limit)
        return [JobOut.of(j, live.get(j.id)) for j in found]

    return svc.read(load)


def get_job(svc: Services, who: Caller, job_id: int) -> JobOut:
    """One job."""
    require(who, Role.VIEWER)
    live = _live(svc).get(job_id)
    return svc.read(lambda s: JobOut.of(jobs.get_job(s, job_id), live))


def cancel_job(svc: Services, who: Caller, job_id: int) -> JobOut:
    """Cancel a queued job, or ask a running one to stop at its next safe point (a
    drip-feed within a chunk); the request is a row, whichever server runs the job."""
    require(who, Role.OPERATOR)
    return svc.write(lambda s: JobOut.of(jobs.cancel(s, job_id, actor=who.name)))


def move_job(svc: Services, who: Caller, job_id: int, index: int) -> JobOut:
    """Put a queued job at ``index`` (0 = next) in its machine's queue."""
    require(who, Role.OPERATOR)
    return svc.write(lambda s: JobOut.of(jobs.move(s, job_id, index, actor=who.name)))


def retry_job(svc: Services, who: Caller, job_id: int, from_line: int | None = None) -> JobOut:
    """Queue a failed, interrupted or cancelled job again, under the rules a new one of its
    kind meets (a drip-feed: programmers, on a machine that still allows it; a send's program
    check, whose override the job keeps)."""
    require(who, Role.OPERATOR)
    old_job = get_job(svc, who, job_id)
    kept = old_job.params.get("check_override")
    override = None
    if isinstance(kept, str):  # the override the job was queued with, by whoever queued it
        override = policy.Override(old_job.created_by, kept)
    wanted = None
    if old_job.program is not None:
        wanted = policy.Wanted(old_job.program, old_job.version)
    prepared = policy.authorize(
        svc,
        who,
        wanted,
        [old_job.machine],
        policy.Action.retry(old_job.kind),
        override=override,
    )

    def retry(session: Session) -> JobOut:
        decision = prepared.confirm(session)
        decision.require_all()
        job = jobs.retry(session, job_id, actor=who.name, from_line=from_line)
        for verdict in decision.allowed:
            if verdict.overridden:
                policy.record_override(session, decision, verdict, job_id=job.id)
        return JobOut.of(job)

    out = svc.write(retry)
    svc.queued([out])
    return out
