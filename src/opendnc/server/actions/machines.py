"""Machine actions: the configured machines, their live state, and what their cards tell of
their jobs."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from datetime import datetime

from sqlalchemy import select
from sqlalchemy.orm import Session, joinedload

from opendnc.server.actions.base import Caller, Services, require
from opendnc.server.actions.models import MachineOut
from opendnc.server.jobs import queue as jobs
from opendnc.server.store.models import Job, ProgramVersion, Role

__all__ = ["CardJobs", "LastJob", "card_jobs", "get_machine", "job_label", "list_machines"]


def list_machines(svc: Services, who: Caller) -> list[MachineOut]:
    """Every configured machine with its live state."""
    require(who, Role.VIEWER)
    return [MachineOut.model_validate(m.as_json()) for m in svc.runner.machines.values()]


def get_machine(svc: Services, who: Caller, name: str) -> MachineOut:
    """One machine with its live state."""
    require(who, Role.VIEWER)
    return MachineOut.model_validate(svc.machine(name).as_json())


@dataclass(frozen=True)
class LastJob:
    """A machine's most recently finished job, as its card tells it."""

    label: str  # "send O1000.nc v2"
    state: str  # done, failed, cancelled, interrupted
    finished: datetime | None
    error: str = ""


@dataclass(frozen=True)
class CardJobs:
    """What the machines' cards tell of their jobs, read in one transaction: the queued jobs
    per machine (those with none left out), the labels of the jobs asked about (``""`` for
    one gone from the table) and the last finished job of each machine asked about (those
    with none left out)."""

    queued: dict[str, int]
    labels: dict[int, str] = field(default_factory=dict)
    last: dict[str, LastJob] = field(default_factory=dict)


def card_jobs(
    svc: Services, who: Caller, *, labels: Sequence[int] = (), last_of: Sequence[str] = ()
) -> CardJobs:
    """The queue lengths, the labels of the jobs ``labels`` and the last finished job of the
    machines ``last_of`` (viewers): one query each, however many machines (two hundred jobs
    start at once when a program goes to every machine)."""
    require(who, Role.VIEWER)

    def load(session: Session) -> CardJobs:
        found = jobs.last_finished(session, list(last_of)) if last_of else {}
        last = {
            name: LastJob(job_label(job), job.state.value, job.finished, job.error)
            for name, job in found.items()
        }
        return CardJobs(jobs.queue_lengths(session), _labels(session, list(labels)), last)

    return svc.read(load)


def job_label(job: Job) -> str:
    """What a card calls ``job``: its kind and program version, or the path it works on."""
    if job.version is not None:
        return f"{job.kind.value} {job.version.program.name} v{job.version.number}"
    # a report names its program; a receive, delete or put its path on the control
    return f"{job.kind.value} {job.params.get('name') or job.params.get('path') or ''}".strip()


def _labels(session: Session, ids: list[int]) -> dict[int, str]:
    if not ids:
        return {}
    stmt = (
        select(Job)
        .where(Job.id.in_(ids))
        .options(joinedload(Job.version).joinedload(ProgramVersion.program))
    )
    found = {job.id: job_label(job) for job in session.scalars(stmt).unique()}
    return {i: found.get(i, "") for i in ids}
