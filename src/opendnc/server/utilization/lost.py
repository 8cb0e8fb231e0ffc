"""Lost time per downtime reason, summed per machine and local day (and week) of the shop's
calendar, so a question over months does not read every stop (docs/dashboard.md#oee).

A year of 200 machines holds about 1.5 million stops (:mod:`.sums`: 5 minutes or more not
running). The Pareto and the lost time per period count every one of them by the period it
began in, with the reason picked for it (:mod:`.downtime`). So once every stop that began on
a local day is over and summed (``utilization_stretches``), the day's stops are summed per
slot (a shift's part of the day, or the time outside shifts, as ``utilization_days``) and per
reason into ``utilization_lost_days``; a week into ``utilization_lost_weeks`` when its last
day is (migration 0020). ``utilization_day_marks.lost_until`` says how far they go: never
past the start of a stop still going.

A reason picked for a stop of a summed day sums that day (and its week) again
(:func:`repick`); a late sample that sums a machine's hours again drops its lost days from
the first stop summed again (:func:`forget_lost`). A question (:func:`lost_of`) reads the
days it holds whole from these rows, and the stops before and after them one by one.
"""

from __future__ import annotations

import bisect
from collections import defaultdict
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from datetime import date, datetime, time, timedelta
from typing import Any

from sqlalchemy import Table, and_, delete, func, insert, select
from sqlalchemy.orm import Session

from opendnc.server.config.downtime import NO_REASON
from opendnc.server.core.shifts import Calendar, Period
from opendnc.server.core.state import State
from opendnc.server.store.models import (
    DowntimeReason,
    UtilizationDayMark,
    UtilizationLostDay,
    UtilizationLostWeek,
    UtilizationMark,
    UtilizationStretch,
)
from opendnc.server.utilization.days import BUILD_DAYS, calendar_key, pieces_of, rolls_up
from opendnc.server.utilization.downtime import StopWithReason
from opendnc.server.utilization.sums import Group, Stretch, as_utc

__all__ = [
    "Lost",
    "build_lost",
    "forget_lost",
    "lost_of",
    "repick",
    "stops_with_reasons",
]

_DAYS: Table = UtilizationLostDay.__table__  # type: ignore[assignment]
_WEEKS: Table = UtilizationLostWeek.__table__  # type: ignore[assignment]
_S = UtilizationStretch.__table__.c
_MARKS: Table = UtilizationMark.__table__  # type: ignore[assignment]
_R = DowntimeReason.__table__.c


def _midnight(calendar: Calendar, day: date) -> datetime:
    return calendar.instant(day, time(0))


def _day_of(calendar: Calendar, at: datetime) -> date:
    return calendar.local(at).date()


def _monday(day: date) -> date:
    return day - timedelta(days=day.weekday())


def _open_stop(mark: UtilizationMark | None) -> datetime | None:
    """The start of the stop going on where ``mark``'s machine is summed up to."""
    if mark is None:
        return None
    value = (mark.carry or {}).get("stop_start")
    return as_utc(datetime.fromisoformat(value)) if value else None


def build_lost(
    session: Session,
    calendar: Calendar,
    machines: Sequence[str],
    marks: dict[str, UtilizationMark],
    limit: int | None = BUILD_DAYS,
) -> int:
    """Sum the lost time of the days of ``machines`` whose days are summed and whose stops
    are all over, at most ``limit`` days per machine; how many machine-days. Call in a write
    transaction, after :func:`.days.build_days`."""
    if not rolls_up(calendar):
        return 0
    key = calendar_key(calendar)
    day_marks = session.scalars(
        select(UtilizationDayMark).where(UtilizationDayMark.machine.in_(list(machines)))
    )
    built = 0
    for mark in day_marks:
        if mark.calendar != key:
            continue
        if mark.lost_until is None:
            first = session.scalar(
                select(func.min(_S.start)).where(_S.machine == mark.machine, _S.kind == "stop")
            )
            begin = _day_of(calendar, as_utc(first)) if first is not None else None
            mark.lost_until = _midnight(calendar, begin) if begin is not None else mark.until
            mark.lost_until = min(mark.lost_until, mark.until)
        since = _day_of(calendar, mark.lost_until)
        until = _day_of(calendar, mark.until)
        going = _open_stop(marks.get(mark.machine))
        if going is not None:
            until = min(until, _day_of(calendar, going))  # its day is not over for stops
        if limit is not None:
            until = min(until, since + timedelta(days=limit))
        if until <= since:
            continue
        _build(session, calendar, mark.machine, since, until)
        mark.lost_until = _midnight(calendar, until)
        built += (until - since).days
    session.flush()
    return built


def _stops_of(
    session: Session, machine: str, since: datetime, until: datetime
) -> list[tuple[datetime, float, str]]:
    """(start, seconds, reason) of ``machine``'s summed stops that began in the span."""
    rows = session.execute(
        select(_S.start, _S.seconds, _R.reason)
        .select_from(UtilizationStretch.__table__)
        .outerjoin(DowntimeReason.__table__, and_(_R.machine == _S.machine, _R.start == _S.start))
        .where(_S.machine == machine, _S.kind == "stop", _S.start >= since, _S.start < until)
    )
    return [(as_utc(a), float(s), r or "") for a, s, r in rows]


def _build(session: Session, calendar: Calendar, machine: str, since: date, until: date) -> None:
    """Sum ``machine``'s stops that began on the days ``[since, until)`` per slot and reason,
    and the weeks whose last day is among them."""
    pieces = [p for d in _days(since, until) for p in pieces_of(calendar, d)]
    starts = [p.start for p in pieces]
    # (the time outside shifts before and after them is one slot of the day, as in days.py)
    sums: dict[tuple[date, str, date, str], list[float]] = {}
    lo, hi = _midnight(calendar, since), _midnight(calendar, until)
    for start, seconds, reason in _stops_of(session, machine, lo, hi):
        p = pieces[bisect.bisect_right(starts, start) - 1]
        held = sums.setdefault((p.day, p.shift, p.shift_day, reason), [0, 0.0])
        held[0] += 1
        held[1] += seconds
    rows = [
        {
            "machine": machine,
            "day": day,
            "shift": shift,
            "shift_day": shift_day,
            "reason": reason,
            "week": _monday(day),
            "stops": int(stops),
            "seconds": seconds,
        }
        for (day, shift, shift_day, reason), (stops, seconds) in sums.items()
    ]
    if rows:
        session.connection().execute(insert(_DAYS), rows)
    first, last = _monday(since), until - timedelta(days=7)  # the weeks that end here
    if first <= last:
        d = _DAYS.c
        session.connection().execute(
            insert(_WEEKS).from_select(
                ["machine", "week", "reason", "stops", "seconds"],
                select(d.machine, d.week, d.reason, func.sum(d.stops), func.sum(d.seconds))
                .where(d.machine == machine, d.week >= first, d.week <= last)
                .group_by(d.machine, d.week, d.reason),
            )
        )


def _days(since: date, until: date) -> Iterable[date]:
    day = since
    while day < until:
        yield day
        day += timedelta(days=1)


def forget_lost(
    session: Session, calendar: Calendar | None, machine: str, at: datetime | None
) -> None:
    """Drop ``machine``'s lost days from the one holding ``at`` on (all of them with
    ``at`` None, without the calendar or with another one): summed again when the stops
    are."""
    mark = session.get(UtilizationDayMark, machine)
    if at is None or calendar is None or mark is None or mark.calendar != calendar_key(calendar):
        session.execute(delete(_DAYS).where(_DAYS.c.machine == machine))
        session.execute(delete(_WEEKS).where(_WEEKS.c.machine == machine))
        if mark is not None:
            mark.lost_until = None
        return
    day = _day_of(calendar, at)
    session.execute(delete(_DAYS).where(_DAYS.c.machine == machine, _DAYS.c.day >= day))
    session.execute(
        delete(_WEEKS).where(_WEEKS.c.machine == machine, _WEEKS.c.week >= _monday(day))
    )
    if mark.lost_until is not None:
        mark.lost_until = min(mark.lost_until, _midnight(calendar, day))


def repick(session: Session, calendar: Calendar, machine: str, start: datetime) -> None:
    """A reason was picked for ``machine``'s stop that began at ``start``: if its day is
    summed, sum that day (and its week, if summed) again."""
    mark = session.get(UtilizationDayMark, machine)
    if mark is None or mark.lost_until is None or mark.calendar != calendar_key(calendar):
        return
    day = _day_of(calendar, start)
    if _midnight(calendar, day) >= mark.lost_until:
        return  # not summed yet: the day is summed with the reason when it is
    d, w = _DAYS.c, _WEEKS.c
    session.execute(delete(_DAYS).where(d.machine == machine, d.day == day))
    week = _monday(day)
    whole_week = session.scalar(
        select(func.count()).select_from(_WEEKS).where(w.machine == machine, w.week == week)
    )
    session.execute(delete(_WEEKS).where(w.machine == machine, w.week == week))
    _build(session, calendar, machine, day, day + timedelta(days=1))
    if not whole_week:  # (_build wrote the week only if this day ends it)
        session.execute(delete(_WEEKS).where(w.machine == machine, w.week == week))
    elif day.weekday() != 6:
        session.connection().execute(
            insert(_WEEKS).from_select(
                ["machine", "week", "reason", "stops", "seconds"],
                select(d.machine, d.week, d.reason, func.sum(d.stops), func.sum(d.seconds))
                .where(d.machine == machine, d.week == week)
                .group_by(d.machine, d.week, d.reason),
            )
        )


@dataclass
class Lost:
    """The stops of some machines over a span summed per reason: per machine and period
    (by the period a stop began in; ``None``: in none), and per machine over all of it."""

    periods: dict[str, dict[int | None, dict[str, float]]] = field(default_factory=dict)
    totals: dict[str, dict[str, list[float]]] = field(default_factory=dict)  # [stops, seconds]

    def add(
        self, machine: str, period: int | None, reason: str, stops: int, seconds: float
    ) -> None:
        """Count ``stops`` stops of ``seconds`` of ``machine`` in ``period``."""
        name = reason or NO_REASON
        mine = self.periods.setdefault(machine, {}).setdefault(period, {})
        mine[name] = mine.get(name, 0.0) + seconds
        held = self.totals.setdefault(machine, {}).setdefault(name, [0, 0.0])
        held[0] += stops
        held[1] += seconds


def _period_at(periods: Sequence[Period], starts: list[datetime], at: datetime) -> int | None:
    i = bisect.bisect_right(starts, at) - 1
    return i if i >= 0 and periods[i].start <= at < periods[i].end else None


def longest_stop(session: Session, machines: Sequence[str]) -> timedelta:
    """The length of the longest summed stop of ``machines`` (a second more, for the
    rounding of its stored seconds): a stop that reaches past an instant began at most this
    long before it, so a query can bound the stops' starts (their index) on both sides.
    One index seek per machine (every machine with summed stops has a mark)."""
    if not machines:
        return timedelta(0)
    inner = UtilizationStretch.__table__.alias("longest")
    t = inner.c
    per_machine = (
        select(t.seconds)
        .where(t.machine == _MARKS.c.machine, t.kind == "stop")
        .order_by(t.seconds.desc())
        .limit(1)
        .scalar_subquery()
    )
    most = select(per_machine.label("seconds")).where(_MARKS.c.machine.in_(list(machines)))
    seconds = session.execute(select(func.max(most.subquery().c.seconds))).scalar()
    return timedelta(seconds=float(seconds or 0.0) + 1.0)


def stops_with_reasons(
    session: Session,
    machines: Sequence[str],
    lo: datetime,
    hi: datetime,
    *,
    before: datetime | None = None,
    after: datetime | None = None,
) -> dict[str, list[StopWithReason]]:
    """The summed stops of ``machines`` that overlap ``[lo, hi)`` with their reasons; with
    ``before`` and ``after`` only those that began before ``before`` or from ``after`` on
    (the stops of the days between come summed)."""
    out: dict[str, list[StopWithReason]] = {m: [] for m in machines}
    if not machines:
        return out
    spans: list[list[Any]] = [[_S.end > lo, _S.start < hi]]
    if before is not None and after is not None:
        # two ranges of the index by start, not every stop between them: those that began
        # before ``before`` and reach into the span began at most the longest stop before it
        reach = lo - longest_stop(session, machines)
        spans = [
            [_S.start >= reach, _S.start < min(before, hi), _S.end > lo],
            [_S.start >= max(after, before), _S.start < hi, _S.end > lo],
        ]
    for where in spans:
        for chunk in range(0, len(machines), 200):
            rows = session.execute(
                select(_S.machine, _S.start, _S.end, _S.state, _S.text, _R.reason, _R.note, _R.by)
                .select_from(UtilizationStretch.__table__)
                .outerjoin(
                    DowntimeReason.__table__, and_(_R.machine == _S.machine, _R.start == _S.start)
                )
                .where(_S.machine.in_(machines[chunk : chunk + 200]), _S.kind == "stop", *where)
            )
            for machine, a, b, state, text, reason, note, by in rows:
                stop = Stretch("stop", as_utc(a), as_utc(b), State(state), text)
                out[machine].append(
                    StopWithReason(machine, stop, reason or "", note or "", by or "")
                )
    return out


def covered_days(
    session: Session,
    calendar: Calendar,
    machines: Sequence[str],
    start: datetime,
    until: datetime,
) -> tuple[date, date] | None:
    """The whole local days within ``[start, until)`` whose lost time every machine has
    summed (None: none)."""
    if not machines or not rolls_up(calendar):
        return None
    key = calendar_key(calendar)
    marks = list(
        session.scalars(
            select(UtilizationDayMark).where(UtilizationDayMark.machine.in_(list(machines)))
        )
    )
    if len(marks) < len(machines) or any(m.calendar != key or m.lost_until is None for m in marks):
        return None
    first = _day_of(calendar, start)
    if _midnight(calendar, first) < start:
        first += timedelta(days=1)
    last = _day_of(calendar, until)
    summed = min(m.lost_until for m in marks if m.lost_until is not None)
    last = min(last, _day_of(calendar, summed))
    return (first, last) if last > first else None


def lost_of(
    session: Session,
    calendar: Calendar,
    machines: Sequence[str],
    periods: Sequence[Period],
    group: Group,
    start: datetime,
    until: datetime,
    days: tuple[date, date] | None,
    stops: dict[str, list[StopWithReason]],
) -> Lost:
    """The lost time of ``machines`` over ``[start, until)`` per reason: the summed ``days``
    (from :func:`covered_days`) from their rows, and ``stops`` (every stop outside those
    days that overlaps the span, clipped at ``until``) one by one."""
    lost = Lost()
    starts = [p.start for p in periods]
    for machine in machines:
        for s in stops.get(machine, []):
            lost.add(machine, _period_at(periods, starts, s.stop.start), s.reason, 1, s.seconds)
    if days is None:
        return lost
    lo, hi = _midnight(calendar, days[0]), _midnight(calendar, days[1])
    key_period = _key_periods(calendar, group, days, periods, starts)
    if key_period is None:  # pragma: no cover - the calendar's own periods cut no key
        more = stops_with_reasons(session, machines, lo, hi)
        for machine, found in more.items():
            for s in found:
                if lo <= s.stop.start < hi:
                    p = _period_at(periods, starts, s.stop.start)
                    seconds = (min(s.stop.end, until) - s.stop.start).total_seconds()
                    lost.add(machine, p, s.reason, 1, seconds)
        return lost
    for machine, key, reason, count, seconds in _read(session, machines, group, days):
        lost.add(machine, key_period.get(key), reason, int(count), float(seconds))
    # a stop of those days still going at ``until`` counts up to it (it began at most the
    # longest stop before ``until``: the start's index from there, not the whole span)
    reach = until - longest_stop(session, machines)
    for machine, a, b, reason in session.execute(
        select(_S.machine, _S.start, _S.end, _R.reason)
        .select_from(UtilizationStretch.__table__)
        .outerjoin(DowntimeReason.__table__, and_(_R.machine == _S.machine, _R.start == _S.start))
        .where(
            _S.machine.in_(list(machines)),
            _S.kind == "stop",
            _S.end > until,
            _S.start >= max(lo, reach),
            _S.start < hi,
        )
    ):
        over = (as_utc(b) - until).total_seconds()
        lost.add(machine, _period_at(periods, starts, as_utc(a)), reason or "", 0, -over)
    return lost


def _key_periods(
    calendar: Calendar,
    group: Group,
    days: tuple[date, date],
    periods: Sequence[Period],
    starts: list[datetime],
) -> dict[Any, int | None] | None:
    """The period each key of the rows (a day, a week's Monday, a shift) of ``days`` falls
    in; None if a key would fall in two."""
    out: dict[Any, int | None] = {}
    for day in _days(*days):
        for p in pieces_of(calendar, day):
            if group is Group.DAY:
                key: Any = p.day
            elif group is Group.WEEK:
                key = _monday(p.day)
            else:
                key = (p.shift, p.shift_day) if p.shift else ("", None)
            at = _period_at(periods, starts, p.start)
            if out.setdefault(key, at) != at:
                return None
    return out


def _read(
    session: Session, machines: Sequence[str], group: Group, days: tuple[date, date]
) -> list[tuple[str, Any, str, int, float]]:
    """(machine, key, reason, stops, seconds) of the summed ``days``, per ``group`` key."""
    d, w = _DAYS.c, _WEEKS.c
    names = list(machines)
    spans = [days]
    out: list[tuple[str, Any, str, int, float]] = []
    if group is Group.WEEK:
        first, last = _monday(days[0] + timedelta(days=6)), _monday(days[1])
        if first < last:
            spans = [(a, b) for a, b in ((days[0], first), (last, days[1])) if a < b]
            for week_row in session.execute(
                select(w.machine, w.week, w.reason, w.stops, w.seconds).where(
                    w.machine.in_(names), w.week >= first, w.week < last
                )
            ):
                out.append(tuple(week_row))
    for a, b in spans:
        if group is Group.SHIFT:
            keys: list[Any] = [d.shift, d.shift_day]
        else:
            keys = [d.day if group is Group.DAY else d.week]
        for row in session.execute(
            select(d.machine, *keys, d.reason, func.sum(d.stops), func.sum(d.seconds))
            .where(d.machine.in_(names), d.day >= a, d.day < b)
            .group_by(d.machine, *keys, d.reason)
        ):
            if group is Group.SHIFT:
                key: Any = (row[1], row[2]) if row[1] else ("", None)
                out.append((row[0], key, row[3], row[4], row[5]))
            else:
                out.append((row[0], row[1], row[2], row[3], row[4]))
    return out


def by_machine(found: Iterable[StopWithReason]) -> dict[str, list[StopWithReason]]:
    """Stops grouped by machine."""
    out: dict[str, list[StopWithReason]] = defaultdict(list)
    for s in found:
        out[s.machine].append(s)
    return out
