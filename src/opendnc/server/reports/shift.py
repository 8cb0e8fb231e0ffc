"""The shift report: one shift of the shop's calendar, its utilization, OEE, parts, its
longest stops with their reasons and its alarms, computed by :func:`.answer.full_report`
(the same figures the utilization page and the API give for that shift)."""

from __future__ import annotations

from dataclasses import dataclass
from datetime import UTC, date, datetime, timedelta

from sqlalchemy.orm import Session, sessionmaker

from opendnc.errors import InputError
from opendnc.server.config.shop import ShopConfig
from opendnc.server.core.errors import NotFound
from opendnc.server.core.shifts import Period
from opendnc.server.utilization.answer import csv_text, full_report
from opendnc.server.utilization.collect import Group, Report
from opendnc.server.utilization.downtime import StopWithReason
from opendnc.server.utilization.sums import AlarmSummary

__all__ = ["LONGEST", "ShiftReport", "build", "last_finished", "shift_period"]

LONGEST = 10  # stops listed


@dataclass(frozen=True)
class ShiftReport:
    """One shift's report."""

    period: Period
    report: Report
    stops: list[StopWithReason]  # the longest, all machines
    alarms: list[tuple[str, AlarmSummary]]  # (machine, alarm) per text
    finished: bool  # the shift is over (else: so far)

    @property
    def csv(self) -> str:
        """The shift's utilization and OEE as the utilization CSV."""
        return csv_text(self.report)

    @property
    def day(self) -> date:
        """The day the shift began (shop's clock)."""
        return self.report.calendar.local(self.period.start).date()


def shift_period(config: ShopConfig, day: date, shift: str) -> Period:
    """The period of ``shift`` that began on ``day``; :class:`NotFound` otherwise."""
    cal = config.calendar
    if not cal.shifts:
        raise NotFound("no shifts are configured ([[shifts]] in the server's configuration)")
    start = cal.instant(day, datetime.min.time())
    for p in cal.shift_periods(start, start + timedelta(days=2)):
        if p.shift == shift and cal.local(p.start).date() == day:
            return p
    names = ", ".join(s.name for s in cal.shifts)
    raise NotFound(f"no shift {shift!r} on {day.isoformat()} (shifts: {names})")


def last_finished(config: ShopConfig, now: datetime) -> Period | None:
    """The shift that ended last before ``now`` (within a week), or None."""
    cal = config.calendar
    ended = [p for p in cal.shift_periods(now - timedelta(days=7), now) if p.end <= now]
    return ended[-1] if ended else None


def build(
    sessions: sessionmaker[Session],
    config: ShopConfig,
    period: Period,
    now: datetime | None = None,
) -> ShiftReport:
    """The report of ``period`` (a shift) for every configured machine."""
    now = now or datetime.now(UTC)
    if period.start >= now:
        raise InputError("that shift has not begun")
    names = [m.name for m in config.machines]
    r = full_report(sessions, config, names, period.start, period.end, Group.SHIFT, now)
    stops = sorted(
        (s for m in (r.floor.machines if r.floor else []) for s in m.stops),
        key=lambda s: (-s.seconds, s.stop.start),
    )[:LONGEST]
    alarms = sorted(
        ((m.machine, a) for m in r.machines for a in m.alarms), key=lambda x: -x[1].seconds
    )
    return ShiftReport(period, r, stops, alarms, period.end <= now)
