"""Utilization summed per machine, local day and shift: what a question over months reads.

A year of 200 machines is 1.75 million summed hours (:mod:`opendnc.server.utilization.collect`);
summing them for every question takes seconds. So every finished local day of the shop's
calendar is summed once more, per **slot**: each shift's part of the day, and the time
outside shifts (``utilization_days``, migration 0014). A day, a week or a shift of a question
is then a sum of a few of these rows; the hours (and the samples) are read only for the days
a span cuts at its ends.

A day row is the sum of the day's hour rows, so it answers exactly what those hours answer.
That needs every boundary of the day (its midnights, each shift's start and end) on a full
UTC hour: true for a zone whose offset is whole hours (Europe/Berlin, America/Chicago) with
shifts on the hour. A calendar with a shift at 05:30, a zone like Asia/Kolkata, or shifts
that overlap, is not summed per day: its questions keep reading the hours.

Days are built from the hours as these are summed (the server's background summing, a
question's short write transaction), at most :data:`BUILD_DAYS` per machine at a time, and
kept per calendar: a changed ``[server] timezone`` or ``[[shifts]]`` builds them again. A
sample that arrives late for a summed hour drops its machine's days from that day on.

A year by week is still 240 000 day rows for 200 machines, so each week of the calendar is
summed once more from its day rows when its last day is (``utilization_weeks``, migration
0016: all the time and the shift time per state in one row): a question by week reads the
weeks it holds whole from these, and only the days before and after them from the days. A
week row goes with any of its days.
"""

from __future__ import annotations

import bisect
import functools
import hashlib
import itertools
from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass, field
from datetime import UTC, date, datetime, time, timedelta
from typing import Any

from sqlalchemy import (
    Column,
    ColumnElement,
    Date,
    MetaData,
    String,
    Table,
    case,
    delete,
    func,
    insert,
    select,
    true,
)
from sqlalchemy.orm import Session

from opendnc.server.core.shifts import Calendar
from opendnc.server.core.state import State
from opendnc.server.store.models import (
    UtcDateTime,
    UtilizationDay,
    UtilizationDayMark,
    UtilizationHour,
    UtilizationLostDay,
    UtilizationLostWeek,
    UtilizationMark,
    UtilizationWeek,
)
from opendnc.server.utilization.sums import STATES, Bin, Figures, Group

__all__ = [
    "BUILD_DAYS",
    "Piece",
    "build_days",
    "calendar_key",
    "day_span",
    "forget_days",
    "pieces_of",
    "rolls_up",
    "sum_days",
]

BUILD_DAYS = 62  # days per machine summed in one go (a write transaction stays short)


_DAYS: Table = UtilizationDay.__table__  # type: ignore[assignment]


_HOURS: Table = UtilizationHour.__table__  # type: ignore[assignment]


_WEEKS: Table = UtilizationWeek.__table__  # type: ignore[assignment]


_NAMES = [s.value for s in STATES]
_RECORD = STATES.index(State.NO_RECORD)  # where no record is in a row's list of states


# which day and slot each hour being summed into days goes to (this connection's own)
_HOUR_PIECES = Table(
    "utilization_hour_pieces",
    MetaData(),
    Column("hour", UtcDateTime(), primary_key=True),
    Column("day", Date, nullable=False),
    Column("shift", String(32), nullable=False),
    Column("shift_day", Date, nullable=False),
    Column("week", Date, nullable=False),
    prefixes=["TEMPORARY"],
)


@dataclass(frozen=True)
class Piece:
    """A part of a local ``day`` in one slot: within the shift ``shift`` that began on
    ``shift_day``, or outside shifts (``shift`` empty), as UTC instants ``[start, end)``."""

    day: date
    shift: str
    shift_day: date
    start: datetime
    end: datetime


def calendar_key(calendar: Calendar) -> str:
    """A digest of the zone and the shifts: day rows are valid for this calendar only."""
    text = (
        calendar.zone_name
        + "|"
        + ";".join(
            f"{s.name},{sorted(s.days)},{s.start.isoformat()},{s.end.isoformat()},{s.ends_at_midnight}"
            for s in calendar.shifts
        )
    )
    return hashlib.sha256(text.encode()).hexdigest()[:32]


def _on_the_hour(at: datetime) -> bool:
    return at.minute == 0 and at.second == 0 and at.microsecond == 0


@functools.lru_cache(maxsize=32)
def rolls_up(calendar: Calendar) -> bool:
    """Whether ``calendar``'s days can be summed from whole hours: shifts on the hour that
    do not overlap, in a zone whose offset is whole hours (checked around the year)."""
    if any(s.start.minute or s.end.minute for s in calendar.shifts):
        return False
    year = datetime.now(UTC).year
    for month in range(1, 13):
        offset = datetime(year, month, 1, tzinfo=calendar.zone).utcoffset() or timedelta(0)
        if offset % timedelta(hours=1):
            return False
    monday = date(year, 1, 5) - timedelta(days=date(year, 1, 5).weekday())
    a = calendar.instant(monday, time(0))
    periods = calendar.shift_periods(a, a + timedelta(days=15))
    return all(x.end <= y.start for x, y in itertools.pairwise(periods))


def pieces_of(calendar: Calendar, day: date) -> list[Piece]:
    """Local ``day`` cut at its shifts' starts and ends, in time order."""
    return list(_pieces(calendar, day))


@functools.lru_cache(maxsize=8192)
def _pieces(calendar: Calendar, day: date) -> tuple[Piece, ...]:
    start = calendar.instant(day, time(0))
    end = calendar.instant(day + timedelta(days=1), time(0))
    shifts = calendar.shift_periods(start, end)
    cuts = {start, end}
    for p in shifts:
        cuts.update(t for t in (p.start, p.end) if start < t < end)
    edges = sorted(cuts)
    out = []
    for a, b in itertools.pairwise(edges):
        covering = [p for p in shifts if p.start <= a < p.end]
        if covering:
            p = covering[-1]
            out.append(Piece(day, p.shift, date.fromisoformat(p.key[:10]), a, b))
        else:
            out.append(Piece(day, "", day, a, b))
    return tuple(out)


def _midnight(calendar: Calendar, day: date) -> datetime:
    return calendar.instant(day, time(0))


def _day_of(calendar: Calendar, at: datetime) -> date:
    return calendar.local(at).date()


def build_days(
    session: Session,
    calendar: Calendar,
    machines: Sequence[str],
    marks: dict[str, UtilizationMark],
    limit: int | None = BUILD_DAYS,
) -> int:
    """Sum the finished local days of ``machines`` (those whose hours are all summed, by
    ``marks``) not summed yet, at most ``limit`` per machine; how many machine-days that
    was. Call in a write transaction, after the hours."""
    if not rolls_up(calendar):
        return 0
    key = calendar_key(calendar)
    names = [m for m in machines if m in marks]
    days = {
        d.machine: d
        for d in session.scalars(
            select(UtilizationDayMark).where(UtilizationDayMark.machine.in_(names))
        )
    }
    todo: dict[tuple[date, date], list[str]] = defaultdict(list)
    for machine in names:
        mark = days.get(machine)
        if mark is None or mark.calendar != key:
            _drop_all(session, machine)
            first = session.scalar(
                select(func.min(UtilizationHour.hour)).where(UtilizationHour.machine == machine)
            )
            begin = _day_of(calendar, first if first is not None else marks[machine].until)
            if mark is None:
                mark = UtilizationDayMark(machine=machine)
                session.add(mark)
            mark.calendar, mark.until = key, _midnight(calendar, begin)
            mark.lost_until = None  # (utilization/lost.py sums them again)
        since = _day_of(calendar, mark.until)
        until = _day_of(calendar, marks[machine].until)  # its midnight is summed; the day not
        if limit is not None:
            until = min(until, since + timedelta(days=limit))
        day = since
        while day < until and all_on_the_hour(pieces_of(calendar, day)):
            day += timedelta(days=1)
        until = day  # (a zone that once had a half-hour offset stops there)
        if until > since:
            todo[(since, until)].append(machine)
            mark.until = _midnight(calendar, until)
    built = 0
    for (since, until), group in todo.items():
        _build(session, calendar, group, since, until)
        _build_weeks(session, calendar, group, since, until)
        built += (until - since).days * len(group)
    session.flush()
    return built


def _build(
    session: Session, calendar: Calendar, machines: list[str], since: date, until: date
) -> None:
    pieces: list[dict[str, object]] = []
    day = since
    while day < until:
        for p in pieces_of(calendar, day):
            hour = p.start
            while hour < p.end:
                pieces.append(
                    {
                        "hour": hour,
                        "day": p.day,
                        "shift": p.shift,
                        "shift_day": p.shift_day,
                        "week": p.day - timedelta(days=p.day.weekday()),
                    }
                )
                hour += timedelta(hours=1)
        day += timedelta(days=1)
    connection = session.connection()
    _HOUR_PIECES.create(connection, checkfirst=True)
    connection.execute(delete(_HOUR_PIECES))
    connection.execute(insert(_HOUR_PIECES), pieces)
    h, s = _HOURS.c, _HOUR_PIECES.c
    states = [s_.value for s_ in STATES]
    query = (
        select(
            h.machine,
            s.day,
            s.shift,
            s.shift_day,
            s.week,
            *(func.sum(h[name]) for name in states),
            func.sum(h.parts),
            func.sum(h.runs),
            func.sum(h.cycles),
            func.sum(h.cycle_seconds),
        )
        .join(_HOUR_PIECES, s.hour == h.hour)
        .where(
            h.machine.in_(machines),
            h.hour >= _midnight(calendar, since),
            h.hour < _midnight(calendar, until),
        )
        .group_by(h.machine, s.day, s.shift, s.shift_day, s.week)
    )
    columns = [
        "machine",
        "day",
        "shift",
        "shift_day",
        "week",
        *states,
        "parts",
        "runs",
        "cycles",
        "cycle_seconds",
    ]
    connection.execute(insert(_DAYS).from_select(columns, query))
    connection.execute(delete(_HOUR_PIECES))


def _monday(day: date) -> date:
    return day - timedelta(days=day.weekday())


def _in_shift(calendar: Calendar) -> ColumnElement[bool]:
    """Which day rows are shift time (a shop without shifts schedules every hour: its
    pieces have no shift's name)."""
    return _DAYS.c.shift != "" if calendar.shifts else true()


def _build_weeks(
    session: Session, calendar: Calendar, machines: list[str], since: date, until: date
) -> None:
    """Sum the weeks whose last day is among the days ``[since, until)`` just summed (their
    earlier days were summed before) from their day rows."""
    first, last = _monday(since), until - timedelta(days=7)  # the Mondays of those weeks
    if last < first:
        return
    d = _DAYS.c
    in_shift = _in_shift(calendar)
    query = (
        select(
            d.machine,
            d.week,
            *(func.sum(d[name]) for name in _NAMES),
            *(func.sum(case((in_shift, d[name]), else_=0.0)) for name in _NAMES),
            func.sum(d.parts),
            func.sum(d.runs),
            func.sum(d.cycles),
            func.sum(d.cycle_seconds),
        )
        .where(
            d.machine.in_(machines),
            d.day >= first,
            d.day < until,
            d.week >= first,
            d.week <= last,
        )
        .group_by(d.machine, d.week)
    )
    columns = [
        "machine",
        "week",
        *_NAMES,
        *(f"shift_{name}" for name in _NAMES),
        "parts",
        "runs",
        "cycles",
        "cycle_seconds",
    ]
    session.connection().execute(insert(_WEEKS).from_select(columns, query))


def _drop_all(session: Session, machine: str) -> None:
    """Drop every summed day and week of ``machine``, and their lost time."""
    for table in (UtilizationDay, UtilizationWeek, UtilizationLostDay, UtilizationLostWeek):
        session.execute(delete(table).where(table.machine == machine))


def forget_days(session: Session, calendar: Calendar | None, machine: str, at: datetime) -> None:
    """Drop ``machine``'s days from the one holding ``at`` on (its hours from ``at`` on are
    summed again): they are summed again from the hours when those are. Without the
    calendar (or with another one than they were summed for) all of them."""
    mark = session.get(UtilizationDayMark, machine)
    if mark is None:
        return
    if calendar is None or mark.calendar != calendar_key(calendar):
        _drop_all(session, machine)
        session.delete(mark)
        return
    day = _day_of(calendar, at)
    session.execute(
        delete(UtilizationDay).where(UtilizationDay.machine == machine, UtilizationDay.day >= day)
    )
    session.execute(  # the week holding that day is not whole any more
        delete(UtilizationWeek).where(
            UtilizationWeek.machine == machine, UtilizationWeek.week >= _monday(day)
        )
    )
    mark.until = min(mark.until, _midnight(calendar, day))


def day_span(
    session: Session,
    calendar: Calendar,
    machines: Sequence[str],
    marks: dict[str, UtilizationMark],
    start: datetime,
    end: datetime,
) -> tuple[date, date] | None:
    """The whole local days ``[first, last)`` within ``[start, end)`` that every machine
    has summed, or None (too few, or the calendar is not summed per day)."""
    if not rolls_up(calendar) or not marks:
        return None
    key = calendar_key(calendar)
    days = list(
        session.scalars(
            select(UtilizationDayMark).where(UtilizationDayMark.machine.in_(list(marks)))
        )
    )
    if len(days) < len(marks) or any(d.calendar != key for d in days):
        return None  # a machine with hours but no days (being built, or a new calendar)
    first = _day_of(calendar, start)
    if _midnight(calendar, first) < start:
        first += timedelta(days=1)
    last = _day_of(calendar, end)
    summed = _day_of(calendar, min(d.until for d in days))
    last = min(last, summed)
    if last - first < timedelta(days=2):
        return None  # a day or two: the hours answer as fast
    return first, last


def sum_days(
    session: Session,
    calendar: Calendar,
    machines: Sequence[str],
    span: tuple[date, date],
    group: Group,
    bins: Sequence[Bin],
    slot_ids: dict[tuple[int | None, bool], int],
    acc: dict[str, dict[int, Figures]],
) -> bool:
    """Add the day rows of ``span`` into ``acc`` per machine and ``group`` period (summed
    in SQL by day, week or shift, under a slot of the period); False (nothing added) if a
    piece of a day lies across two bins or a key across two periods (not the calendar's
    own periods)."""
    layout = _layout(calendar, span, group, bins, slot_ids)
    if layout is None:
        return False
    keys = _group_keys(group)
    rows = _read_rows(session, calendar, machines, span, group, keys)
    k = 1 + len(keys)
    rows_of: dict[str, dict[int, Any]] = {m: {} for m in machines}
    for row in rows:
        at = layout.period_of.get(tuple(row[1:k]))
        if at is None:  # pragma: no cover - every day of the span was cut into pieces
            return False
        rows_of[row[0]][at] = row
    # (a year per day is 73 000 of these: plain lists, one Figures each)
    for machine in machines:
        mine, into = rows_of[machine], acc[machine]
        for period, (whole, inside) in layout.length.items():
            f = _figures_of(mine.get(period), k, whole, inside)
            slot = layout.slot_of[period]
            held = into.get(slot)
            if held is None:
                into[slot] = f
            else:
                held.add(f)
    return True


@dataclass
class _Layout:
    """How the pieces of a span's days fall into a question's periods: the period of each
    key (day, week or shift), each period's length (all of it, the shift time) and slot."""

    period_of: dict[tuple[object, ...], int] = field(default_factory=dict)
    length: dict[int, list[float]] = field(default_factory=dict)
    slot_of: dict[int, int] = field(default_factory=dict)


def _layout(
    calendar: Calendar,
    span: tuple[date, date],
    group: Group,
    bins: Sequence[Bin],
    slot_ids: dict[tuple[int | None, bool], int],
) -> _Layout | None:
    """Each piece of each day of ``span`` laid into the bin it lies in; None if a piece lies
    across two bins or a key across two periods."""
    ends = [b.end for b in bins]
    out = _Layout()
    day = span[0]
    while day < span[1]:
        for p in pieces_of(calendar, day):
            j = bisect.bisect_right(ends, p.start)
            if j >= len(bins) or bins[j].end < p.end or bins[j].start > p.start:
                return None
            b = bins[j]
            period = -1 if b.period is None else b.period
            if out.period_of.setdefault(_key(group, p), period) != period:
                return None
            seconds = (p.end - p.start).total_seconds()
            total = out.length.setdefault(period, [0.0, 0.0])
            total[0] += seconds
            if b.in_shift:
                total[1] += seconds
            out.slot_of.setdefault(period, slot_ids[(b.period, b.in_shift)])
        day += timedelta(days=1)
    return out


def _group_keys(group: Group) -> list[Any]:
    """The columns of a day row that name its period when grouped by ``group``."""
    d = _DAYS.c
    by_group: dict[Group, list[Any]] = {
        Group.DAY: [d.day],
        Group.WEEK: [d.week],
        Group.SHIFT: [d.shift, case((d.shift == "", None), else_=d.shift_day)],
    }
    return by_group[group]


def _read_rows(
    session: Session,
    calendar: Calendar,
    machines: Sequence[str],
    span: tuple[date, date],
    group: Group,
    keys: list[Any],
) -> list[Any]:
    """Rows of (machine, keys, seconds per state, shift seconds per state, parts, part rows,
    runs, cycles, cycle seconds) per machine and period of ``span``."""
    days = [span]
    weeks = None
    if group is Group.WEEK:
        # the whole weeks of the span from the week rows, the days before and after them
        # from the day rows (a year is 52 rows per machine instead of 1 200)
        first = _monday(span[0] + timedelta(days=6))
        last = _monday(span[1])
        if first < last:
            weeks = (first, last)
            days = [(a, b) for a, b in ((span[0], first), (last, span[1])) if a < b]
    in_shift = _in_shift(calendar)
    connection = session.connection()
    d = _DAYS.c
    rows: list[Any] = []
    for since, until in days:  # (the two ends of a span by week fall in two different weeks)
        rows += connection.execute(
            select(
                d.machine,
                *keys,
                *(func.sum(d[name]) for name in _NAMES),
                *(func.sum(case((in_shift, d[name]), else_=0.0)) for name in _NAMES),
                func.sum(d.parts),
                func.count(d.parts),
                func.sum(d.runs),
                func.sum(d.cycles),
                func.sum(d.cycle_seconds),
            )
            .where(d.machine.in_(machines), d.day >= since, d.day < until)
            .group_by(d.machine, *keys)
        ).all()
    if weeks is not None:
        rows += _read_weeks(session, machines, weeks)
    return rows


def _read_weeks(session: Session, machines: Sequence[str], weeks: tuple[date, date]) -> list[Any]:
    """The week rows of ``weeks`` in the columns of the day rows' sums."""
    w = _WEEKS.c
    return list(
        session.connection().execute(
            select(
                w.machine,
                w.week,
                *(w[name] for name in _NAMES),
                *(w[f"shift_{name}"] for name in _NAMES),
                w.parts,
                case((w.parts.is_(None), 0), else_=1),  # as the days' count of parts
                w.runs,
                w.cycles,
                w.cycle_seconds,
            ).where(w.machine.in_(machines), w.week >= weeks[0], w.week < weeks[1])
        )
    )


def _figures_of(row: Any | None, k: int, whole: float, inside: float) -> Figures:
    """One machine's figures of one period from its summed row (columns from ``k`` on; None:
    no row), the period being ``whole`` seconds long, ``inside`` of them shift time."""
    n = len(STATES)
    if row is None:
        spent, planned = [0.0] * n, [0.0] * n
        parts, runs, cycles, cycle_seconds = None, 0, 0, 0.0
    else:
        spent = [float(v or 0.0) for v in row[k : k + n]]
        planned = [float(v or 0.0) for v in row[k + n : k + 2 * n]]
        parts = int(row[k + 2 * n] or 0) if row[k + 2 * n + 1] else None
        runs, cycles = int(row[k + 2 * n + 2] or 0), int(row[k + 2 * n + 3] or 0)
        cycle_seconds = float(row[k + 2 * n + 4] or 0.0)
    # pieces without a row are time without any record (those hours were not stored)
    shift_time = sum(planned)
    shift_missing = inside - shift_time
    off_missing = (whole - inside) - (sum(spent) - shift_time)
    if shift_missing > 0.5:
        spent[_RECORD] += shift_missing
        planned[_RECORD] += shift_missing
    if off_missing > 0.5:
        spent[_RECORD] += off_missing
    return Figures(
        dict(zip(STATES, spent, strict=True)),
        dict(zip(STATES, planned, strict=True)),
        parts,
        runs,
        cycles,
        cycle_seconds,
    )


def _key(group: Group, p: Piece) -> tuple[object, ...]:
    """What the day rows of ``p`` are grouped by for ``group``."""
    if group is Group.DAY:
        return (p.day,)
    if group is Group.WEEK:
        return (p.day - timedelta(days=p.day.weekday()),)
    return (p.shift, p.shift_day if p.shift else None)


def all_on_the_hour(pieces: Sequence[Piece]) -> bool:
    """Whether every piece starts and ends on a full UTC hour."""
    return all(_on_the_hour(p.start) and _on_the_hour(p.end) for p in pieces)
