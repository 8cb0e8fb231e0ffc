"""The shop floor's own entries: a standard cycle time for a program version (a supervisor's:
approver and up), parts reported good and scrapped, and the reason for a stop (an
operator's and up). Each writes its audit row in the same transaction
(docs/dashboard.md#oee, #downtime-reasons)."""

from __future__ import annotations

from dataclasses import dataclass
from datetime import UTC, datetime, timedelta

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from opendnc.errors import InputError
from opendnc.server.actions.base import Caller, Services, require
from opendnc.server.library import versions as library
from opendnc.server.store import audit
from opendnc.server.store.models import (
    DowntimeReason,
    PartReport,
    Program,
    Role,
    StandardTime,
    utcnow,
)
from opendnc.server.utilization.lost import repick
from opendnc.server.utilization.oee import standards_for
from opendnc.server.utilization.sums import as_utc

__all__ = [
    "MAX_PARTS",
    "MAX_STANDARD",
    "NOTE_MAX",
    "PartsOut",
    "ReasonOut",
    "StandardOut",
    "StandardRow",
    "pick_reason",
    "report_parts",
    "set_standard",
    "standards",
]

MAX_PARTS = 100_000  # parts in one report: more is a typing slip
MAX_STANDARD = 7 * 24 * 3600.0  # seconds: a standard cycle of a week at most
NOTE_MAX = 200  # characters of a note


@dataclass(frozen=True)
class StandardOut:
    """A standard cycle time set."""

    program: str
    version: int
    seconds: float
    set_by: str


@dataclass(frozen=True)
class PartsOut:
    """Parts reported."""

    id: int
    machine: str
    at: datetime
    good: int
    scrap: int
    by: str


@dataclass(frozen=True)
class ReasonOut:
    """The reason now recorded for a stop."""

    machine: str
    start: datetime
    reason: str
    by: str


@dataclass(frozen=True)
class StandardRow:
    """One program's standard cycle time as OEE counts it: the version its name stands for
    (the newest released, else the newest), the time in use and where it comes from."""

    program: str
    version: int | None
    seconds: float | None
    source: str  # "set" (by a supervisor), "estimate" (the check's), "" (none)
    estimate: float | None  # the check's estimate: what a new standard starts from
    set_by: str
    set_at: datetime | None


def standards(svc: Services, who: Caller) -> list[StandardRow]:
    """Every program's standard time (approvers and up: they set them), by name."""
    require(who, Role.APPROVER)

    def work(session: Session) -> list[StandardRow]:
        names = list(session.scalars(select(Program.name).order_by(func.lower(Program.name))))
        found = standards_for(session, names)
        ids = [s.version_id for s in found.values() if s.source == "set"]
        who_set = {
            r.version_id: r
            for r in session.scalars(select(StandardTime).where(StandardTime.version_id.in_(ids)))
        }
        out = []
        for name in names:
            std = found.get(name.lower())
            if std is None:
                continue
            row = who_set.get(std.version_id) if std.version_id is not None else None
            out.append(
                StandardRow(
                    std.program, std.version, std.seconds, std.source, std.estimate,
                    row.set_by if row is not None else "",
                    as_utc(row.set_at) if row is not None else None,
                )
            )  # fmt: skip
        return out

    return svc.read(work)


def _note(note: str) -> str:
    note = " ".join(note.split())
    if len(note) > NOTE_MAX:
        raise InputError(f"note: at most {NOTE_MAX} characters")
    return note


def set_standard(
    svc: Services, who: Caller, program: str, number: int | None, seconds: float
) -> StandardOut:
    """Set the standard cycle time of a program version (the newest without ``number``)."""
    require(who, Role.APPROVER)
    if not 0 < seconds <= MAX_STANDARD:
        raise InputError(f"seconds: expected more than 0 and at most {MAX_STANDARD:.0f}")

    def work(session: Session) -> StandardOut:
        version = library.get_version(session, program, number)
        row = session.get(StandardTime, version.id)
        before = row.seconds if row is not None else None
        if row is None:
            row = StandardTime(version_id=version.id, seconds=seconds, set_by=who.name)
            session.add(row)
        else:
            row.seconds, row.set_by, row.set_at = seconds, who.name, utcnow()
        audit.record(
            session,
            who.name,
            "standard.set",
            program=version.program.name,
            sha256=version.sha256,
            version=version.number,
            seconds=seconds,
            before=before,
        )
        return StandardOut(version.program.name, version.number, seconds, who.name)

    return svc.write(work)


def report_parts(
    svc: Services,
    who: Caller,
    machine: str,
    good: int,
    scrap: int,
    note: str = "",
    at: datetime | None = None,
) -> PartsOut:
    """Report parts made on ``machine``: good and scrapped ones (counted in the period that
    holds ``at``, now by default; never in the future)."""
    require(who, Role.OPERATOR)
    svc.machine(machine)
    if not (0 <= good <= MAX_PARTS and 0 <= scrap <= MAX_PARTS) or good + scrap == 0:
        raise InputError(f"good and scrap: 0 to {MAX_PARTS} each, at least one part")
    now = datetime.now(UTC)
    when = now if at is None else as_utc(at)
    if when > now + timedelta(minutes=1):
        raise InputError("at: parts are reported once made, not ahead")
    text = _note(note)

    def work(session: Session) -> PartsOut:
        row = PartReport(machine=machine, at=when, good=good, scrap=scrap, by=who.name, note=text)
        session.add(row)
        session.flush()
        audit.record(
            session, who.name, "parts.report", machine=machine, good=good, scrap=scrap, note=text
        )
        return PartsOut(row.id, machine, when, good, scrap, who.name)

    return svc.write(work)


def pick_reason(
    svc: Services, who: Caller, machine: str, start: datetime, reason: str, note: str = ""
) -> ReasonOut:
    """Record why ``machine``'s stop that began at ``start`` happened (one of ``[downtime]
    reasons``); picking again replaces the reason."""
    require(who, Role.OPERATOR)
    svc.machine(machine)
    reasons = svc.runner.config.downtime.reasons
    chosen = next((r for r in reasons if r.lower() == reason.strip().lower()), None)
    if chosen is None:
        raise InputError(f"reason: expected one of {', '.join(reasons)}, got {reason!r}")
    if start.tzinfo is None:
        raise InputError("start: the stop's start needs a UTC offset")
    began = start.astimezone(UTC)
    if began > datetime.now(UTC):
        raise InputError("start: a stop that has not begun")
    text = _note(note)

    def work(session: Session) -> ReasonOut:
        row = session.scalar(
            select(DowntimeReason).where(
                DowntimeReason.machine == machine, DowntimeReason.start == began
            )
        )
        before = row.reason if row is not None else None
        if row is None:
            row = DowntimeReason(machine=machine, start=began, reason=chosen, note=text)
            session.add(row)
        row.reason, row.note, row.by, row.at = chosen, text, who.name, utcnow()
        session.flush()
        # a stop of a day whose lost time is summed: that day is summed again with it
        repick(session, svc.runner.config.calendar, machine, began)
        audit.record(
            session,
            who.name,
            "downtime.reason",
            machine=machine,
            start=began.isoformat(),
            reason=chosen,
            before=before,
            note=text,
        )
        return ReasonOut(machine, began, chosen, who.name)

    return svc.write(work)
