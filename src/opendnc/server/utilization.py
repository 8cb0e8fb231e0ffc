"""Utilization from the stored status timeline: time per state, parts, runs, stops and alarms,
per machine and per shift, day or week of the shop's calendar (:mod:`opendnc.server.shifts`).

The samples are ``status_samples`` (one row per change of a machine's state, program, part
counter or alarm; server/web/timeline.py); the arithmetic and the definitions are
:mod:`opendnc.server.utilization_sums` (docs/dashboard.md#utilization).

A year of 200 machines is too many samples to read for every question (about 20 million at a
change every 5 minutes), so finished hours are summed once into ``utilization_hours`` and
``utilization_stretches`` (migration 0007) and a question sums those in SQL, mapping each
hour to its period and to shift or not; only the hours that are not finished yet, and those
a period or shift boundary cuts, are read from the samples. Hours are UTC: a boundary on the
full hour in a zone with a whole-hour offset (Europe/Berlin) never cuts one. A sample that
arrives late for an hour already summed (the recorder's queue while the database was away)
has its machine summed again from a day before it.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from typing import Any

from sqlalchemy import (
    Column,
    Integer,
    MetaData,
    String,
    Table,
    TypeDecorator,
    delete,
    func,
    insert,
    select,
    type_coerce,
    union_all,
)
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from opendnc.errors import InputError
from opendnc.server.shifts import Calendar, Period
from opendnc.server.state import State
from opendnc.server.store.models import (
    StatusSample,
    UtcDateTime,
    UtilizationHour,
    UtilizationMark,
    UtilizationStretch,
)
from opendnc.server.utilization_sums import (
    HOUR,
    STATES,
    TOP_STOPS,
    AlarmSummary,
    Bin,
    Carry,
    Figures,
    Group,
    MachineReport,
    Point,
    Stretch,
    as_utc,
    bin_at,
    bins_within,
    ceil_hour,
    equal_periods,
    floor_hour,
    follow,
    in_force,
    machine_report,
    make_bins,
    open_stretches,
    periods_of,
    point_of,
    point_of_columns,
    stored_state,
    summarize,
    sweep,
)

__all__ = [
    "STATES",
    "AlarmSummary",
    "Bin",
    "Carry",
    "Figures",
    "Group",
    "MachineReport",
    "Point",
    "Report",
    "Stretch",
    "buckets",
    "equal_periods",
    "make_bins",
    "point_of",
    "read_many",
    "report",
    "roll",
    "stored_state",
    "sum_safely",
    "summarize",
    "sweep",
]


log = logging.getLogger(__name__)


ROLL_MARGIN = timedelta(minutes=2)  # the recorder writes within seconds; leave it room


REWIND = timedelta(days=1)  # how far before a late sample its machine is summed again


_roll_lock = threading.Lock()


_HOURS: Table = UtilizationHour.__table__  # type: ignore[assignment]


_STRETCHES: Table = UtilizationStretch.__table__  # type: ignore[assignment]


# which slot (period, shift or not) each summed hour of a question goes to
_SLOTS = Table(
    "utilization_slots",
    MetaData(),
    Column("hour", UtcDateTime(), primary_key=True),
    Column("slot", Integer, nullable=False),
    prefixes=["TEMPORARY"],
)


class _FastUtc(TypeDecorator[datetime]):
    """A stored time read without SQLAlchemy's per-row SQLite date parsing (a year of
    samples is millions of rows): ISO text through the C parser, or the driver's datetime."""

    impl = String
    cache_ok = True

    def process_result_value(self, value: Any, dialect: Any) -> datetime | None:
        if value is None:
            return None
        at: datetime = datetime.fromisoformat(value) if isinstance(value, str) else value
        return at if at.tzinfo else at.replace(tzinfo=UTC)


_AT = type_coerce(StatusSample.at, _FastUtc()).label("at")


_SAMPLE_COLUMNS = (
    StatusSample.machine,
    StatusSample.id,
    _AT,
    StatusSample.state,
    StatusSample.execution,
    StatusSample.program,
    StatusSample.part_count,
    StatusSample.alarm,
)


UNION_CHUNK = 200  # per-machine subqueries in one statement (SQLite allows 500)


def _chunks(items: Sequence[str], size: int = UNION_CHUNK) -> Iterator[Sequence[str]]:
    for i in range(0, len(items), size):
        yield items[i : i + size]


def read_points(session: Session, machine: str, start: datetime, end: datetime) -> list[Point]:
    """``machine``'s samples in ``[start, end)`` and the one in force at ``start``."""
    return read_many(session, [machine], start, end)[machine]


def read_many(
    session: Session, machines: Sequence[str], start: datetime, end: datetime
) -> dict[str, list[Point]]:
    """Each machine's samples in ``[start, end)`` and the one in force at ``start``, in two
    statements for all of them (one index seek per machine for the one in force)."""
    out: dict[str, list[Point]] = {m: [] for m in machines}
    for chunk in _chunks(machines):
        before = union_all(
            *(
                select(*_SAMPLE_COLUMNS)
                .where(StatusSample.machine == m, StatusSample.at < start)
                .order_by(StatusSample.at.desc(), StatusSample.id.desc())
                .limit(1)
                .subquery()
                .select()
                for m in chunk
            )
        )
        for row in session.execute(before):
            out[row[0]].append(point_of_columns(row))
        rows = session.execute(
            select(*_SAMPLE_COLUMNS)
            .where(StatusSample.machine.in_(chunk), StatusSample.at >= start, StatusSample.at < end)
            .order_by(StatusSample.machine, StatusSample.at, StatusSample.id)
        )
        for row in rows:
            out[row[0]].append(point_of_columns(row))
    return out


def roll(session: Session, machines: Iterable[str], now: datetime) -> int:
    """Sum the finished hours of ``machines`` not summed yet (up to the hour before ``now``
    less a margin); how many machine-hours were written. Call in a write transaction."""
    target = floor_hour(now - ROLL_MARGIN)
    written = 0
    with _roll_lock:
        marks = {m.machine: m for m in session.scalars(select(UtilizationMark))}
        seen = max((m.last_id for m in marks.values()), default=0)
        late = session.execute(
            select(StatusSample.machine, func.min(StatusSample.at))
            .where(StatusSample.id > seen)
            .group_by(StatusSample.machine)
        ).all()
        last_id = session.scalar(select(func.max(StatusSample.id))) or 0
        for machine, first in late:
            mark = marks.get(machine)
            first = first if first.tzinfo else first.replace(tzinfo=UTC)
            if mark is not None and first < mark.until:
                # a sample for an hour already summed: sum this machine again from a day
                # before it (what carries into that point is read from the samples there)
                _rewind(session, mark, floor_hour(first) - REWIND)
        for machine in machines:
            written += _roll_machine(session, machine, marks.get(machine), target, last_id)
    return written


def _rewind(session: Session, mark: UtilizationMark, at: datetime) -> None:
    """Forget ``mark``'s machine's sums from ``at`` on (not before its first sample still
    kept: hours whose samples were pruned stay as they were summed)."""
    machine = mark.machine
    first = session.scalar(select(func.min(_AT)).where(StatusSample.machine == machine))
    if first is not None:
        at = max(at, floor_hour(first))
    session.execute(
        delete(UtilizationHour).where(
            UtilizationHour.machine == machine, UtilizationHour.hour >= at
        )
    )
    session.execute(
        delete(UtilizationStretch).where(
            UtilizationStretch.machine == machine, UtilizationStretch.end > at
        )
    )
    before = read_many(session, [machine], at, at)[machine]
    mark.until = at
    mark.carry = Carry.fresh(before[-1] if before else None).as_json()


def _roll_machine(
    session: Session, machine: str, mark: UtilizationMark | None, target: datetime, last_id: int
) -> int:
    if mark is None:
        first = session.scalar(
            select(func.min(StatusSample.at)).where(StatusSample.machine == machine)
        )
        if first is None:
            return 0
        start = floor_hour(first if first.tzinfo else first.replace(tzinfo=UTC))
        carry = Carry()
    else:
        start, carry = mark.until, Carry.from_json(mark.carry)
    if start >= target:
        return 0
    points = read_points(session, machine, start, target)
    hours = int((target - start) / HOUR)
    bins = [Bin(start + k * HOUR, start + (k + 1) * HOUR) for k in range(hours)]
    stretches: list[Stretch] = []
    figures = sweep(points, start, target, bins, carry, stretches)
    rows = [
        {
            "machine": machine,
            "hour": b.start,
            **{s.value: f.seconds[s] for s in STATES},
            "parts": f.parts,
            "runs": f.runs,
            "cycles": f.cycles,
            "cycle_seconds": f.cycle_seconds,
        }
        for b, f in zip(bins, figures, strict=True)
        if f.seconds[State.NO_RECORD] < 3600.0 or f.runs or f.parts
    ]
    for chunk in range(0, len(rows), 5000):
        session.connection().execute(insert(_HOURS), rows[chunk : chunk + 5000])
    if stretches:
        session.connection().execute(
            insert(_STRETCHES),
            [
                {
                    "machine": machine,
                    "kind": s.kind,
                    "start": s.start,
                    "end": s.end,
                    "seconds": s.seconds,
                    "state": s.state.value,
                    "text": s.text[:200],
                }
                for s in stretches
            ],
        )
    if mark is None:
        session.add(
            UtilizationMark(machine=machine, until=target, last_id=last_id, carry=carry.as_json())
        )
    else:
        mark.until, mark.last_id, mark.carry = target, last_id, carry.as_json()
    return len(rows)


@dataclass
class Report:
    """Utilization of some machines over ``[start, end)``, per ``group`` period."""

    start: datetime
    end: datetime
    group: Group
    calendar: Calendar
    periods: list[Period]
    machines: list[MachineReport]


MAX_SPAN = timedelta(days=400)


def report(
    session: Session,
    calendar: Calendar,
    machines: Sequence[str],
    start: datetime,
    end: datetime,
    group: Group = Group.DAY,
    *,
    now: datetime | None = None,
    use_hours: bool = True,
    sum_first: bool = True,
) -> Report:
    """Utilization of ``machines`` over ``[start, end)``. Finished hours not summed yet are
    summed first (a write transaction), unless ``sum_first=False`` (the caller summed them in
    a short write transaction of its own and reads here). ``use_hours=False`` reads every
    sample (the reference the summed hours are tested against)."""
    if start.tzinfo is None or end.tzinfo is None:
        raise InputError("utilization: times need a UTC offset")
    start, end = start.astimezone(UTC), end.astimezone(UTC)
    if end <= start:
        raise InputError("utilization: the span ends before it starts")
    if end - start > MAX_SPAN:
        raise InputError(f"utilization: at most {MAX_SPAN.days} days at once")
    now = now or datetime.now(UTC)
    periods = periods_of(calendar, group, start, end)
    scheduled = calendar.scheduled(start, end)
    per_period, totals, stretches = _collect(
        session, machines, start, end, periods, scheduled, now, use_hours, sum_first=sum_first
    )
    reports = [
        machine_report(m, totals[m], per_period[m], stretches[m], start, end) for m in machines
    ]
    return Report(start, end, group, calendar, periods, reports)


def buckets(
    session: Session,
    machines: Sequence[str],
    periods: Sequence[Period],
    *,
    now: datetime | None = None,
    sum_first: bool = True,
) -> dict[str, list[Figures]]:
    """The figures of each machine in each of ``periods`` (consecutive, as from
    :func:`equal_periods`): what a Gantt chart draws. Buckets of whole hours come from
    the summed hours."""
    if not periods:
        return {m: [] for m in machines}
    start, end = periods[0].start, periods[-1].end
    per_period, _totals, _stretches = _collect(
        session,
        machines,
        start,
        end,
        list(periods),
        [],
        now or datetime.now(UTC),
        True,
        stretches=False,
        sum_first=sum_first,
    )
    return per_period


def _collect(
    session: Session,
    machines: Sequence[str],
    start: datetime,
    end: datetime,
    periods: list[Period],
    scheduled: list[tuple[datetime, datetime]],
    now: datetime,
    use_hours: bool,
    *,
    stretches: bool = True,
    sum_first: bool = True,
) -> tuple[dict[str, list[Figures]], dict[str, Figures], dict[str, list[Stretch]]]:
    want_stretches = stretches
    bins = make_bins(periods, scheduled, start, end)
    slots = [(b.period, b.in_shift) for b in bins]
    slot_ids = {s: i for i, s in enumerate(dict.fromkeys(slots))}
    acc: dict[str, dict[int, Figures]] = {m: {} for m in machines}
    found_by: dict[str, list[Stretch]] = {m: [] for m in machines}
    tail_from = start
    marks: dict[str, UtilizationMark] = {}
    raw = [(start, end)]
    if use_hours and machines:
        if sum_first:
            sum_safely(session, machines, now)
        marks = {
            m.machine: m
            for m in session.scalars(
                select(UtilizationMark).where(UtilizationMark.machine.in_(machines))
            )
        }
        until = min((m.until for m in marks.values()), default=start)
        raw, hour_slots = _plan(bins, slot_ids, start, end, until)
        in_shift = {i: shift for (_p, shift), i in slot_ids.items()}
        _sum_hours(session, machines, hour_slots, acc, in_shift)
        if want_stretches:
            _stored_stretches(session, machines, start, end, found_by)
        tail_from = max(start, min(until, end))
    pieces = [
        (
            a,
            b,
            [
                Bin(max(x.start, a), min(x.end, b), x.period, x.in_shift)
                for x in bins_within(bins, a, b)
            ],
        )
        for a, b in raw
    ]
    frontiers: dict[str, tuple[Carry, datetime]] = {}  # what is open where the span ends
    for a, b, local_bins in pieces:
        is_tail = a >= tail_from
        if use_hours:
            read = read_many(session, machines, a, b)
        for machine in machines:
            mark = marks.get(machine)
            sweep_from = a
            if not use_hours:
                # the reference: every sample from the machine's first, so what carries
                # into the span (a run, a stop, the counter) is known exactly
                first = session.scalar(
                    select(func.min(StatusSample.at)).where(StatusSample.machine == machine)
                )
                sweep_from = min(a, as_utc(first)) if first is not None else a
                carry = Carry()
                points = read_points(session, machine, sweep_from, b)
            elif is_tail and mark is not None and mark.until == a:
                points = read[machine]
                carry = Carry.from_json(mark.carry)
            else:
                points = read[machine]
                carry = Carry.fresh(in_force(points, a))
            found: list[Stretch] = []
            figs = sweep(points, sweep_from, b, local_bins, carry, found)
            for x, f in zip(local_bins, figs, strict=True):
                acc[machine].setdefault(slot_ids[(x.period, x.in_shift)], Figures()).add(f)
            if is_tail:
                found_by[machine] += found
                if b == end:
                    frontiers[machine] = (carry, end)
    for machine, mark in marks.items():
        if machine not in frontiers and mark.until >= end:
            frontiers[machine] = (Carry.from_json(mark.carry), mark.until)
    if want_stretches:
        _finish_many(session, frontiers, now, found_by)
    per_period: dict[str, list[Figures]] = {}
    totals: dict[str, Figures] = {}
    for machine in machines:
        totals[machine] = Figures()
        per_period[machine] = [Figures() for _ in periods]
        for (period, _shift), slot in slot_ids.items():
            summed = acc[machine].get(slot)
            if summed is None:
                continue
            totals[machine].add(summed)
            if period is not None:
                per_period[machine][period].add(summed)
    return per_period, totals, found_by


FINISH_BATCH = 1000


def _finish(
    session: Session,
    machine: str,
    carry: Carry,
    at: datetime,
    now: datetime,
    out: list[Stretch],
) -> None:
    """Follow the stop and the alarm open at ``at`` through the later samples to their end,
    so a stop that began in the span counts whole; one still open is ``ongoing`` until
    ``now``."""
    while carry.stop_start is not None or carry.alarm_start is not None:
        rows = session.execute(
            select(*_SAMPLE_COLUMNS)
            .where(StatusSample.machine == machine, StatusSample.at >= at)
            .order_by(StatusSample.at, StatusSample.id)
            .limit(FINISH_BATCH)
        ).all()
        points = [point_of_columns(r) for r in rows]
        if not points:
            out += open_stretches(carry, max(now, at))
            return
        follow(points, carry, out)
        if len(points) < FINISH_BATCH:
            if carry.stop_start is not None or carry.alarm_start is not None:
                out += open_stretches(carry, max(now, points[-1].at))
            return
        at = points[-1].at + timedelta(microseconds=1)


FINISH_FIRST = 50  # samples per machine in the first, shared read


def _finish_many(
    session: Session,
    frontiers: dict[str, tuple[Carry, datetime]],
    now: datetime,
    out: dict[str, list[Stretch]],
) -> None:
    """:func:`_finish` for many machines: the first samples of all of them in one statement,
    the rare stop that outlasts those one machine at a time."""
    open_ = {
        m: (c, at)
        for m, (c, at) in frontiers.items()
        if c.stop_start is not None or c.alarm_start is not None
    }
    names = sorted(open_)
    later: dict[str, list[Point]] = {m: [] for m in names}
    for chunk in _chunks(names):
        statement = union_all(
            *(
                select(*_SAMPLE_COLUMNS)
                .where(StatusSample.machine == m, StatusSample.at >= open_[m][1])
                .order_by(StatusSample.at, StatusSample.id)
                .limit(FINISH_FIRST)
                .subquery()
                .select()
                for m in chunk
            )
        )
        for row in session.execute(statement):
            later[row[0]].append(point_of_columns(row))
    for machine in names:
        carry, at = open_[machine]
        points = sorted(later[machine], key=lambda p: p.at)
        follow(points, carry, out[machine])
        if carry.stop_start is None and carry.alarm_start is None:
            continue
        if len(points) < FINISH_FIRST:
            last = points[-1].at if points else at
            out[machine] += open_stretches(carry, max(now, last))
        else:
            _finish(
                session,
                machine,
                carry,
                points[-1].at + timedelta(microseconds=1),
                now,
                out[machine],
            )


def sum_safely(session: Session, machines: Sequence[str], now: datetime) -> None:
    """:func:`roll` in a savepoint: if another server sharing the database summed the same
    hours just now, its sums stand and this one's are dropped."""
    try:
        with session.begin_nested():
            roll(session, machines, now)
    except IntegrityError:
        log.info("utilization: another server summed these hours first")


def _plan(
    bins: Sequence[Bin],
    slot_ids: dict[tuple[int | None, bool], int],
    start: datetime,
    end: datetime,
    until: datetime,
) -> tuple[list[tuple[datetime, datetime]], list[tuple[datetime, int]]]:
    """Which hours come summed (each with its slot), and which spans from the samples."""
    hour_slots: list[tuple[datetime, int]] = []
    raw: list[tuple[datetime, datetime]] = []
    ends = [b.end for b in bins]

    def read(a: datetime, b: datetime) -> None:
        if b <= a:
            return
        if raw and raw[-1][1] == a:
            raw[-1] = (raw[-1][0], b)
        else:
            raw.append((a, b))

    first, last = ceil_hour(start), min(floor_hour(end), until)
    if last <= first:
        read(start, end)
        return raw, hour_slots
    read(start, first)
    hour = first
    while hour < last:
        j = bin_at(hour, ends)
        if j < len(bins) and bins[j].end >= hour + HOUR:
            hour_slots.append((hour, slot_ids[(bins[j].period, bins[j].in_shift)]))
        else:
            read(hour, hour + HOUR)  # a boundary inside the hour
        hour += HOUR
    read(last, end)
    return raw, hour_slots


def _sum_hours(
    session: Session,
    machines: Sequence[str],
    hour_slots: Sequence[tuple[datetime, int]],
    acc: dict[str, dict[int, Figures]],
    in_shift: dict[int, bool],
) -> None:
    """Sum the hours in SQL, per machine and slot (a temporary table maps hour to slot)."""
    if not hour_slots:
        return
    connection = session.connection()
    _SLOTS.create(connection, checkfirst=True)  # temporary: this connection's own
    session.execute(delete(_SLOTS))
    connection.execute(insert(_SLOTS), [{"hour": h, "slot": s} for h, s in hour_slots])
    h = UtilizationHour.__table__.c
    rows = session.execute(
        select(
            h.machine,
            _SLOTS.c.slot,
            *(func.sum(h[s.value]) for s in STATES),
            func.sum(h.parts),
            func.count(h.parts),
            func.sum(h.runs),
            func.sum(h.cycles),
            func.sum(h.cycle_seconds),
        )
        .join(_SLOTS, _SLOTS.c.hour == h.hour)
        .where(
            h.machine.in_(machines),
            h.hour >= hour_slots[0][0],
            h.hour <= hour_slots[-1][0],
        )
        .group_by(h.machine, _SLOTS.c.slot)
    ).all()
    session.execute(delete(_SLOTS))
    for row in rows:
        machine, slot = row[0], int(row[1])
        values = row[2:]
        f = Figures()
        for k, s in enumerate(STATES):
            f.seconds[s] = float(values[k] or 0.0)
        parts_sum, parts_rows, runs, cycles, cycle_seconds = values[len(STATES) :]
        f.parts = int(parts_sum or 0) if parts_rows else None
        if in_shift[slot]:
            f.scheduled = dict(f.seconds)
        f.runs, f.cycles, f.cycle_seconds = (
            int(runs or 0),
            int(cycles or 0),
            float(cycle_seconds or 0),
        )
        acc[machine].setdefault(slot, Figures()).add(f)
    # Hours without a row are hours without any record (not stored, to save space).
    slot_seconds: dict[int, float] = {}
    for _hour, slot in hour_slots:
        slot_seconds[slot] = slot_seconds.get(slot, 0.0) + 3600.0
    by_machine: dict[str, dict[int, float]] = {m: {} for m in machines}
    for row in rows:
        by_machine[row[0]][int(row[1])] = sum(float(v or 0.0) for v in row[2 : 2 + len(STATES)])
    for machine in machines:
        for slot, seconds in slot_seconds.items():
            missing = seconds - by_machine[machine].get(slot, 0.0)
            if missing > 0.5:
                f = acc[machine].setdefault(slot, Figures())
                f.seconds[State.NO_RECORD] += missing
                if in_shift[slot]:
                    f.scheduled[State.NO_RECORD] += missing


def _stored_stretches(
    session: Session,
    machines: Sequence[str],
    start: datetime,
    end: datetime,
    out: dict[str, list[Stretch]],
) -> None:
    """The summed stops (each machine's longest) and alarms (all, by text later) overlapping
    the span: one statement each for all machines."""
    t = UtilizationStretch
    columns = (t.machine, t.kind, t.start, t.end, t.state, t.text)
    overlap = (t.end > start, t.start < end)
    for chunk in _chunks(machines):
        stops = union_all(
            *(
                select(*columns)
                .where(t.machine == m, t.kind == "stop", *overlap)
                .order_by(t.seconds.desc(), t.start)
                .limit(TOP_STOPS)
                .subquery()
                .select()
                for m in chunk
            )
        )
        alarms = select(*columns).where(t.machine.in_(chunk), t.kind == "alarm", *overlap)
        for statement in (stops, alarms):
            for r in session.execute(statement):
                out[r.machine].append(
                    Stretch(r.kind, as_utc(r.start), as_utc(r.end), State(r.state), r.text)
                )
