"""Utilization from the stored status timeline: time per state, parts, runs, stops and alarms,
per machine and per shift, day or week of the shop's calendar (:mod:`opendnc.server.core.shifts`).

The samples are ``status_samples`` (one row per change of a machine's state, program, part
counter or alarm; server/machines/timeline.py); the arithmetic and the definitions are
:mod:`opendnc.server.utilization.sums` (docs/dashboard.md#utilization).

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
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime, time, timedelta
from typing import Any

from sqlalchemy import (
    ARRAY,
    Column,
    Integer,
    MetaData,
    Select,
    String,
    Table,
    TypeDecorator,
    and_,
    bindparam,
    delete,
    func,
    insert,
    select,
    true,
    type_coerce,
)
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from opendnc.errors import InputError
from opendnc.server.core.gc_pause import paused
from opendnc.server.core.shifts import Calendar, Period
from opendnc.server.core.state import State
from opendnc.server.store.models import (
    DowntimeReason,
    StatusSample,
    UtcDateTime,
    UtilizationHour,
    UtilizationMark,
    UtilizationProgramHour,
    UtilizationStretch,
)
from opendnc.server.utilization.days import BUILD_DAYS, build_days, day_span, forget_days, sum_days
from opendnc.server.utilization.lost import build_lost, forget_lost
from opendnc.server.utilization.sums import (
    HOUR,
    RECENT_ALARMS,
    STATES,
    TOP_STOPS,
    AlarmSummary,
    Bin,
    Carry,
    Figures,
    Group,
    MachineReport,
    Point,
    ProgramRuns,
    Stretch,
    SummedAlarms,
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
    "each_machine",
    "equal_periods",
    "make_bins",
    "marks_of",
    "plan_hours",
    "point_of",
    "program_sums",
    "read_many",
    "report",
    "roll",
    "sum_safely",
    "summarize",
    "sweep",
]


log = logging.getLogger(__name__)


LONGEST_READ = 21  # each machine's longest stops read with a report: OEE lists 20 (one more:
# one of them may end after the span, clipped and shorter), the report its TOP_STOPS


Longest = dict[str, list[tuple[Stretch, str, str, str]]]  # per machine: (stop, reason, note, by)


ROLL_MARGIN = timedelta(minutes=2)  # the recorder writes within seconds; leave it room


REWIND = timedelta(days=1)  # how far before a late sample its machine is summed again


_roll_lock = threading.Lock()


_HOURS: Table = UtilizationHour.__table__  # type: ignore[assignment]


_STRETCHES: Table = UtilizationStretch.__table__  # type: ignore[assignment]


_PROGRAM_HOURS: Table = UtilizationProgramHour.__table__  # type: ignore[assignment]


_REASONS: Table = DowntimeReason.__table__  # type: ignore[assignment]


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


_SAMPLES: Table = StatusSample.__table__  # type: ignore[assignment]


# a stretch's start and end as :class:`_FastUtc` reads them
_STRETCH_AT = (
    type_coerce(_STRETCHES.c.start, _FastUtc()).label("start"),
    type_coerce(_STRETCHES.c.end, _FastUtc()).label("end"),
)


_AT = type_coerce(_SAMPLES.c.at, _FastUtc()).label("at")


_SAMPLE_COLUMNS = (
    _SAMPLES.c.machine,
    _SAMPLES.c.id,
    _AT,
    _SAMPLES.c.state,
    _SAMPLES.c.execution,
    _SAMPLES.c.program,
    _SAMPLES.c.part_count,
    _SAMPLES.c.alarm,
)


UNION_CHUNK = 200  # machines in one IN list (SQLite allows 999 parameters)


def _chunks(items: Sequence[str], size: int = UNION_CHUNK) -> Iterator[Sequence[str]]:
    for i in range(0, len(items), size):
        yield items[i : i + size]


def each_machine(
    session: Session,
    make: Callable[[Any], Select[Any]],
    machines: Sequence[str],
    **params: Any,
) -> Iterator[Any]:
    """The rows of ``make(machine)`` (a statement about one machine, typically with a
    ``LIMIT``) for each of ``machines``. On PostgreSQL one statement for all of them (a
    lateral join over the names as one array parameter); elsewhere (SQLite, in process, no
    round trips) the one statement prepared once and run per machine: both cost less than
    compiling one statement of hundreds of parts."""
    connection = session.connection()
    if connection.dialect.name == "postgresql":
        # (render_derived names the column: a bare ``anon_1.name`` would be read by
        # PostgreSQL as ``name(anon_1)``, a cast to its 63-byte identifier type, which cuts
        # longer names and keeps the planner from the machine's indexes)
        names = (
            func.unnest(bindparam("machines", type_=ARRAY(String())))
            .table_valued("name")
            .render_derived()
        )
        each = make(names.c.name).lateral("each")
        statement = select(each).select_from(names).join(each, true())
        yield from connection.execute(statement, {"machines": list(machines), **params})
        return
    prepared = make(bindparam("machine", type_=String()))
    for machine in machines:
        yield from connection.execute(prepared, {"machine": machine, **params})


def read_points(session: Session, machine: str, start: datetime, end: datetime) -> list[Point]:
    """``machine``'s samples in ``[start, end)`` and the one in force at ``start``."""
    return read_many(session, [machine], start, end)[machine]


def read_many(
    session: Session, machines: Sequence[str], start: datetime, end: datetime
) -> dict[str, list[Point]]:
    """Each machine's samples in ``[start, end)`` and the one in force at ``start``, in two
    statements for all of them (one index seek per machine for the one in force)."""
    out: dict[str, list[Point]] = {m: [] for m in machines}
    c = _SAMPLES.c

    def before(machine: Any) -> Select[Any]:
        return (
            select(*_SAMPLE_COLUMNS)
            .where(c.machine == machine, c.at < bindparam("start", type_=UtcDateTime()))
            .order_by(c.at.desc(), c.id.desc())
            .limit(1)
        )

    for row in each_machine(session, before, machines, start=start):
        out[row[0]].append(point_of_columns(row))
    for chunk in _chunks(machines):
        rows = session.execute(
            select(*_SAMPLE_COLUMNS)
            .where(c.machine.in_(chunk), c.at >= start, c.at < end)
            .order_by(c.machine, c.at, c.id)
        )
        for row in rows:
            out[row[0]].append(point_of_columns(row))
    return out


def roll(
    session: Session,
    machines: Iterable[str],
    now: datetime,
    calendar: Calendar | None = None,
    *,
    days: int | None = BUILD_DAYS,
) -> int:
    """Sum the finished hours of ``machines`` not summed yet (up to the hour before ``now``
    less a margin), then (given the shop's ``calendar``) up to ``days`` of their finished
    local days per machine (:mod:`opendnc.server.utilization.days`; None: all of them);
    how many machine-hours were written. Call in a write transaction."""
    target = floor_hour(now - ROLL_MARGIN)
    written = 0
    machines = list(machines)
    with _roll_lock:
        marks = {m.machine: m for m in session.scalars(select(UtilizationMark))}
        seen = max((m.last_id for m in marks.values()), default=0)
        # the samples written since, by their ids first: grouped at once, SQLite would
        # rather walk the whole (machine, at) index in machine order than sort a few rows
        recent = (
            select(StatusSample.machine, StatusSample.at)
            .where(StatusSample.id > seen)
            .order_by(StatusSample.id)
            .subquery()
        )
        late = session.execute(
            select(recent.c.machine, func.min(recent.c.at)).group_by(recent.c.machine)
        ).all()
        last_id = session.scalar(select(func.max(StatusSample.id))) or 0
        for machine, first in late:
            mark = marks.get(machine)
            first = first if first.tzinfo else first.replace(tzinfo=UTC)
            if mark is not None and first < mark.until:
                # a sample for an hour already summed: sum this machine again from a day
                # before it (what carries into that point is read from the samples there)
                _rewind(session, mark, floor_hour(first) - REWIND, calendar)
        for machine in machines:
            written += _roll_machine(session, machine, marks.get(machine), target, last_id)
        if calendar is not None:
            session.flush()
            marks = marks_of(session, machines)
            build_days(session, calendar, machines, marks, days)
            build_lost(session, calendar, machines, marks, days)
    return written


def marks_of(session: Session, machines: Sequence[str] | None = None) -> dict[str, UtilizationMark]:
    """How far each machine's hours are summed (all machines', or those of ``machines``)."""
    query = select(UtilizationMark)
    if machines is not None:
        query = query.where(UtilizationMark.machine.in_(machines))
    return {m.machine: m for m in session.scalars(query)}


def _rewind(
    session: Session, mark: UtilizationMark, at: datetime, calendar: Calendar | None
) -> None:
    """Forget ``mark``'s machine's sums from ``at`` on (not before its first sample still
    kept: hours whose samples were pruned stay as they were summed)."""
    machine = mark.machine
    first = session.scalar(select(func.min(_AT)).where(StatusSample.machine == machine))
    if first is not None:
        at = max(at, floor_hour(first))
    # a stop summed again may have begun before ``at``: its day's lost time goes too
    began = session.scalar(
        select(func.min(UtilizationStretch.start)).where(
            UtilizationStretch.machine == machine,
            UtilizationStretch.kind == "stop",
            UtilizationStretch.end > at,
        )
    )
    session.execute(
        delete(UtilizationHour).where(
            UtilizationHour.machine == machine, UtilizationHour.hour >= at
        )
    )
    session.execute(
        delete(UtilizationProgramHour).where(
            UtilizationProgramHour.machine == machine, UtilizationProgramHour.hour >= at
        )
    )
    session.execute(
        delete(UtilizationStretch).where(
            UtilizationStretch.machine == machine, UtilizationStretch.end > at
        )
    )
    forget_days(session, calendar, machine, at)
    forget_lost(session, calendar, machine, min(at, as_utc(began)) if began is not None else at)
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
    programs: list[dict[str, ProgramRuns]] = [{} for _ in bins]
    figures = sweep(points, start, target, bins, carry, stretches, programs)
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
        # (an hour of no record is not stored, unless it says the machine counts parts)
        if f.seconds[State.NO_RECORD] < 3600.0 or f.runs or f.parts is not None
    ]
    for chunk in range(0, len(rows), 5000):
        session.connection().execute(insert(_HOURS), rows[chunk : chunk + 5000])
    per_program = [
        {"machine": machine, "hour": b.start, "program": name, "runs": r.runs, "seconds": r.seconds}
        for b, by_name in zip(bins, programs, strict=True)
        for name, r in by_name.items()
    ]
    for chunk in range(0, len(per_program), 5000):
        session.connection().execute(insert(_PROGRAM_HOURS), per_program[chunk : chunk + 5000])
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
    until: datetime | None = None  # where the figures end: the span's end, or now within it
    # OEE, parts and stops with reasons (utilization/oee.py), where the question asked for them
    floor: Any = None
    # each machine's longest summed stops with their reasons, read with the report (None:
    # not read, as from every sample): what OEE lists of them
    longest: Longest | None = None


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
    use_days: bool = True,
) -> Report:
    """Utilization of ``machines`` over ``[start, end)``. Finished hours not summed yet are
    summed first (a write transaction), unless ``sum_first=False`` (the caller summed them in
    a short write transaction of its own and reads here). Whole local days come from the
    summed days where there are (``use_days=False``: from the hours), the rest from the
    hours; ``use_hours=False`` reads every sample (the reference both are tested against)."""
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
    summed = {m: SummedAlarms() for m in machines}
    longest: Longest = {}
    with paused():  # (a figure per machine and period: tens of thousands over a year)
        per_period, totals, stretches = _collect(
            session,
            machines,
            start,
            end,
            periods,
            scheduled,
            now,
            use_hours,
            sum_first=sum_first,
            calendar=calendar,
            use_days=use_days,
            group=group,
            alarms_out=summed,
            longest_out=longest,
        )
        reports = [
            machine_report(m, totals[m], per_period[m], stretches[m], start, end, summed[m])
            for m in machines
        ]
    until = min(end, max(start, now))  # nothing after now is counted
    known = longest if use_hours else None
    return Report(start, end, group, calendar, periods, reports, until, longest=known)


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
    with paused():
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


Slots = dict[tuple[int | None, bool], int]  # (period, shift time or not): its number


@dataclass
class _Tally:
    """What one question sums into: the figures of each machine per slot (a period and
    whether it is shift time), and the stops and alarms found per machine."""

    machines: Sequence[str]
    bins: list[Bin]
    slot_ids: Slots
    acc: dict[str, dict[int, Figures]]
    found_by: dict[str, list[Stretch]]

    @classmethod
    def of(cls, machines: Sequence[str], bins: list[Bin]) -> _Tally:
        """An empty tally of ``machines`` over ``bins``, a slot for each (period, shift)."""
        slots = [(b.period, b.in_shift) for b in bins]
        slot_ids = {s: i for i, s in enumerate(dict.fromkeys(slots))}
        return cls(machines, bins, slot_ids, {m: {} for m in machines}, {m: [] for m in machines})

    def add(self, machine: str, piece: Bin, f: Figures) -> None:
        """Add ``machine``'s figures of ``piece`` to the slot it belongs to."""
        slot = self.slot_ids[(piece.period, piece.in_shift)]
        self.acc[machine].setdefault(slot, Figures()).add(f)


@dataclass
class _Summed:
    """What the summed hours and days left over: each machine's mark (how far it is summed),
    the spans still to read from the samples, and where the tail after the marks begins."""

    marks: dict[str, UtilizationMark]
    raw: list[tuple[datetime, datetime]]
    tail_from: datetime


Frontiers = dict[str, tuple[Carry, datetime]]  # per machine: what is open, and from when


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
    calendar: Calendar | None = None,
    use_days: bool = False,
    group: Group | None = None,
    alarms_out: dict[str, SummedAlarms] | None = None,
    longest_out: Longest | None = None,
) -> tuple[dict[str, list[Figures]], dict[str, Figures], dict[str, list[Stretch]]]:
    """Each machine's figures per period and in total over ``[start, end)``, and its stops:
    from the summed days and hours where they hold the time, from the samples elsewhere
    (``use_hours=False``: from every sample, the reference)."""
    if alarms_out is None:
        alarms_out = {m: SummedAlarms() for m in machines}
    # what has not happened yet counts nowhere: a span that holds ``now`` is summed up to
    # ``now`` (the state in force is not stretched to the span's end), and its later periods
    # stay empty, so every percentage is over the time that has passed
    end = min(end, max(start, now))
    tally = _Tally.of(machines, make_bins(periods, scheduled, start, end))
    summed = _Summed({}, [(start, end)], start)
    if use_hours and machines:
        if sum_first:
            sum_safely(session, machines, now, calendar)
        summed = _from_sums(session, tally, start, end, calendar, group if use_days else None)
        if stretches:
            _stored_stretches(
                session, machines, start, end, tally.found_by, alarms_out, longest_out
            )
    frontiers = _sweep_samples(session, tally, summed, end, use_hours)
    for machine, mark in summed.marks.items():
        if machine not in frontiers and mark.until >= end:
            frontiers[machine] = (Carry.from_json(mark.carry), mark.until)
    if stretches:
        _finish_many(session, frontiers, now, tally.found_by)
    per_period, totals = _per_period(tally, len(periods))
    return per_period, totals, tally.found_by


def _from_sums(
    session: Session,
    tally: _Tally,
    start: datetime,
    end: datetime,
    calendar: Calendar | None,
    group: Group | None,
) -> _Summed:
    """Add what the summed days (with a ``group``) and the summed hours hold of
    ``[start, end)`` to ``tally``; what they do not hold is left to read from the samples."""
    machines = tally.machines
    marks = {
        m.machine: m
        for m in session.scalars(
            select(UtilizationMark).where(UtilizationMark.machine.in_(machines))
        )
    }
    until = min((m.until for m in marks.values()), default=start)
    skip = _from_days(session, tally, marks, start, end, calendar, group)
    raw, hour_slots = _plan(tally.bins, tally.slot_ids, start, end, until, skip)
    in_shift = {i: shift for (_p, shift), i in tally.slot_ids.items()}
    # before and after the summed days, so the hours between are not read again
    cut = skip[0] if skip is not None else end
    for run in ([x for x in hour_slots if x[0] < cut], [x for x in hour_slots if x[0] >= cut]):
        _sum_hours(session, machines, run, tally.acc, in_shift)
    return _Summed(marks, raw, max(start, min(until, end)))


def _from_days(
    session: Session,
    tally: _Tally,
    marks: dict[str, UtilizationMark],
    start: datetime,
    end: datetime,
    calendar: Calendar | None,
    group: Group | None,
) -> tuple[datetime, datetime] | None:
    """Add the whole local days of ``[start, end)`` that are summed to ``tally``; the span
    they cover (None: no days were used)."""
    if calendar is None or group is None:
        return None
    machines = tally.machines
    days = day_span(session, calendar, machines, marks, start, end)
    if days is None:
        return None
    if not sum_days(
        session, calendar, machines, days, group, tally.bins, tally.slot_ids, tally.acc
    ):
        return None
    return calendar.instant(days[0], time(0)), calendar.instant(days[1], time(0))


def _sweep_samples(
    session: Session, tally: _Tally, summed: _Summed, end: datetime, use_hours: bool
) -> Frontiers:
    """Sweep the samples of the spans the sums do not hold into ``tally``; what is open at
    ``end`` per machine (a stop that runs on)."""
    frontiers: Frontiers = {}
    for a, b in summed.raw:
        local_bins = [
            Bin(max(x.start, a), min(x.end, b), x.period, x.in_shift)
            for x in bins_within(tally.bins, a, b)
        ]
        is_tail = a >= summed.tail_from
        read = read_many(session, tally.machines, a, b) if use_hours else None
        for machine in tally.machines:
            tail_mark = summed.marks.get(machine) if is_tail else None
            sweep_from, points, carry = _points_of(session, machine, a, b, read, tail_mark)
            found: list[Stretch] = []
            figs = sweep(points, sweep_from, b, local_bins, carry, found)
            for x, f in zip(local_bins, figs, strict=True):
                tally.add(machine, x, f)
            if is_tail:
                tally.found_by[machine] += found
                if b == end:
                    frontiers[machine] = (carry, end)
    return frontiers


def _points_of(
    session: Session,
    machine: str,
    a: datetime,
    b: datetime,
    read: dict[str, list[Point]] | None,
    tail_mark: UtilizationMark | None,
) -> tuple[datetime, list[Point], Carry]:
    """Where ``machine``'s sweep of ``[a, b)`` starts, its points, and what carries into it:
    from ``read`` (the samples read for all machines), or without it from every sample since
    the machine's first."""
    if read is None:
        # the reference: every sample from the machine's first, so what carries into the
        # span (a run, a stop, the counter) is known exactly
        first = session.scalar(
            select(func.min(StatusSample.at)).where(StatusSample.machine == machine)
        )
        sweep_from = min(a, as_utc(first)) if first is not None else a
        return sweep_from, read_points(session, machine, sweep_from, b), Carry()
    points = read[machine]
    if tail_mark is not None and tail_mark.until == a:
        return a, points, Carry.from_json(tail_mark.carry)  # summed up to here: carry on
    return a, points, Carry.fresh(in_force(points, a))


def _per_period(tally: _Tally, periods: int) -> tuple[dict[str, list[Figures]], dict[str, Figures]]:
    """Each machine's slots added up per period, and its total."""
    per_period: dict[str, list[Figures]] = {}
    totals: dict[str, Figures] = {}
    for machine in tally.machines:
        total = totals[machine] = Figures()
        mine: list[Figures | None] = [None] * periods
        for (period, _shift), slot in tally.slot_ids.items():
            summed = tally.acc[machine].get(slot)
            if summed is None:
                continue
            total.add(summed)
            if period is not None:
                held = mine[period]
                if held is None:  # (a year by day has 73 000 of these: no copies)
                    mine[period] = summed
                else:
                    held.add(summed)
        per_period[machine] = [f if f is not None else Figures() for f in mine]
    return per_period, totals


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
            .where(StatusSample.at < now)  # (a stop ends at now at the latest)
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
                out += open_stretches(carry, now)
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
    c = _SAMPLES.c

    def first(machine: Any) -> Select[Any]:
        return (
            select(*_SAMPLE_COLUMNS)
            .where(c.machine == machine, c.at >= bindparam("at", type_=UtcDateTime()))
            .where(c.at < bindparam("now", type_=UtcDateTime()))  # (what is known at now)
            .order_by(c.at, c.id)
            .limit(FINISH_FIRST)
        )

    # each machine's frontier differs: run the one statement per machine
    connection = session.connection()
    prepared = first(bindparam("machine", type_=String()))
    for machine in names:
        params = {"machine": machine, "at": open_[machine][1], "now": now}
        for row in connection.execute(prepared, params):
            later[machine].append(point_of_columns(row))
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


def sum_safely(
    session: Session,
    machines: Sequence[str],
    now: datetime,
    calendar: Calendar | None = None,
    *,
    days: int | None = BUILD_DAYS,
) -> None:
    """:func:`roll` in a savepoint: if another server sharing the database summed the same
    hours just now, its sums stand and this one's are dropped."""
    try:
        with session.begin_nested():
            roll(session, machines, now, calendar, days=days)
    except IntegrityError:
        log.info("utilization: another server summed these hours first")


def _plan(
    bins: Sequence[Bin],
    slot_ids: dict[tuple[int | None, bool], int],
    start: datetime,
    end: datetime,
    until: datetime,
    skip: tuple[datetime, datetime] | None = None,
) -> tuple[list[tuple[datetime, datetime]], list[tuple[datetime, int]]]:
    """Which hours come summed (each with its slot), and which spans from the samples;
    the hours in ``skip`` come from the summed days."""
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
        if skip is not None and skip[0] <= hour < skip[1]:
            hour = skip[1]
            continue
        j = bin_at(hour, ends)
        if j < len(bins) and bins[j].end >= hour + HOUR:
            hour_slots.append((hour, slot_ids[(bins[j].period, bins[j].in_shift)]))
        else:
            read(hour, hour + HOUR)  # a boundary inside the hour
        hour += HOUR
    read(last, end)
    return raw, hour_slots


plan_hours = _plan


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
    rows = _hour_sums(session, machines, hour_slots)
    for row in rows:
        machine, slot = row[0], int(row[1])
        acc[machine].setdefault(slot, Figures()).add(_figures_of(row[2:], in_shift[slot]))
    _no_record_hours(machines, hour_slots, rows, acc, in_shift)


def _hour_sums(
    session: Session, machines: Sequence[str], hour_slots: Sequence[tuple[datetime, int]]
) -> list[Any]:
    """Rows of (machine, slot, seconds per state, parts, part rows, runs, cycles, cycle
    seconds): the summed hours of ``hour_slots`` added up per machine and slot."""
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
    return list(rows)


def program_sums(
    session: Session, machines: Sequence[str], hour_slots: Sequence[tuple[datetime, int]]
) -> list[tuple[str, int, str, int, float]]:
    """Rows of (machine, slot, program, runs, running seconds): the summed runs per program
    of ``hour_slots`` added up per machine, slot and program."""
    if not hour_slots or not machines:
        return []
    connection = session.connection()
    _SLOTS.create(connection, checkfirst=True)  # temporary: this connection's own
    session.execute(delete(_SLOTS))
    connection.execute(insert(_SLOTS), [{"hour": h, "slot": s} for h, s in hour_slots])
    p = _PROGRAM_HOURS.c
    out: list[tuple[str, int, str, int, float]] = []
    for chunk in _chunks(machines):
        rows = session.execute(
            select(p.machine, _SLOTS.c.slot, p.program, func.sum(p.runs), func.sum(p.seconds))
            .join(_SLOTS, _SLOTS.c.hour == p.hour)
            .where(p.machine.in_(chunk), p.hour >= hour_slots[0][0], p.hour <= hour_slots[-1][0])
            .group_by(p.machine, _SLOTS.c.slot, p.program)
        )
        out += [(m, int(slot), name, int(r or 0), float(t or 0.0)) for m, slot, name, r, t in rows]
    session.execute(delete(_SLOTS))
    return out


def _figures_of(values: Sequence[Any], in_shift: bool) -> Figures:
    """The figures of one row of :func:`_hour_sums` (after machine and slot)."""
    f = Figures()
    for k, s in enumerate(STATES):
        f.seconds[s] = float(values[k] or 0.0)
    parts_sum, parts_rows, runs, cycles, cycle_seconds = values[len(STATES) :]
    f.parts = int(parts_sum or 0) if parts_rows else None
    if in_shift:
        f.scheduled = dict(f.seconds)
    f.runs, f.cycles, f.cycle_seconds = (
        int(runs or 0),
        int(cycles or 0),
        float(cycle_seconds or 0),
    )
    return f


def _no_record_hours(
    machines: Sequence[str],
    hour_slots: Sequence[tuple[datetime, int]],
    rows: Sequence[Any],
    acc: dict[str, dict[int, Figures]],
    in_shift: dict[int, bool],
) -> None:
    """Count the time of ``hour_slots`` that no summed hour holds as no record."""
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


LONG_SPAN = timedelta(days=14)  # from here on, most stops of a machine overlap a span


def overlapping(t: Any, start: datetime, end: datetime) -> tuple[Any, Any]:
    """The conditions of a stretch (columns ``t``) overlapping ``[start, end)``, for a query
    that walks the index of stops by length. Over a long span most stops overlap it, so the
    end and the start are compared through a function: the database then keeps to the
    length's index (its first rows are the answer) rather than take the end's or the
    start's and sort every stop of the span (SQLite did: 3 ms a machine). Over a short span
    the few that end in it come by the end's index."""
    if end - start < LONG_SPAN:
        return t.end > start, t.start < end
    return func.coalesce(t.end, t.end) > start, func.coalesce(t.start, t.start) < end


def longest_stops(
    session: Session, machines: Sequence[str], start: datetime, end: datetime
) -> Longest:
    """Each machine's :data:`LONGEST_READ` longest summed stops overlapping ``[start,
    end)``, longest first, each with the reason picked for it: one ``LIMIT`` query per
    machine down the index of stops by length."""
    t = _STRETCHES.c
    r = _REASONS.c
    overlap = overlapping(t, start, end)

    def stops(machine: Any) -> Select[Any]:
        return (
            select(t.machine, *_STRETCH_AT, t.state, t.text, t.seconds, r.reason, r.note, r.by)
            .select_from(_STRETCHES)
            .outerjoin(_REASONS, and_(r.machine == t.machine, r.start == t.start))
            .where(t.machine == machine, t.kind == "stop", *overlap)
            .order_by(t.seconds.desc(), t.start)
            .limit(LONGEST_READ)
        )

    found: dict[str, list[tuple[float, Stretch, str, str, str]]] = {m: [] for m in machines}
    for machine, a, b, state, text, seconds, reason, note, by in each_machine(
        session, stops, machines
    ):
        stop = Stretch("stop", a, b, State(state), text)
        found[machine].append((seconds, stop, reason or "", note or "", by or ""))
    out: Longest = {}
    for machine, rows in found.items():
        rows.sort(key=lambda x: (-x[0], x[1].start))  # (the database's order)
        out[machine] = [x[1:] for x in rows]
    return out


def _stored_stretches(
    session: Session,
    machines: Sequence[str],
    start: datetime,
    end: datetime,
    out: dict[str, list[Stretch]],
    alarms_out: dict[str, SummedAlarms],
    longest_out: Longest | None = None,
) -> None:
    """The summed stops (each machine's longest) and alarms (per text, and the newest)
    overlapping the span: a few statements for all machines. The longest stops are
    :func:`longest_stops`' (with their reasons, for OEE's list: ``longest_out``), of which
    the report keeps :data:`TOP_STOPS`."""
    t = _STRETCHES.c
    columns = (t.machine, t.kind, *_STRETCH_AT, t.state, t.text)
    longest = longest_stops(session, machines, start, end)
    for machine, rows in longest.items():
        out[machine] += [x[0] for x in rows[:TOP_STOPS]]
    if longest_out is not None:
        longest_out.update(longest)

    def recent(machine: Any) -> Select[Any]:
        # a machine's alarms follow one another: the newest to start are the newest to end
        return (
            select(*columns)
            .where(t.machine == machine, t.kind == "alarm", t.end > start, t.start < end)
            .order_by(t.end.desc())
            .limit(RECENT_ALARMS)
        )

    for r in each_machine(session, recent, machines):
        alarms_out[r.machine].recent.append(Stretch(r.kind, r.start, r.end, State(r.state), r.text))
    for chunk in _chunks(machines):
        per_text = (
            select(t.machine, t.text, func.count(), func.sum(t.seconds), func.max(t.seconds))
            .where(t.machine.in_(chunk), t.kind == "alarm", t.end > start, t.start < end)
            .group_by(t.machine, t.text)
        )
        for machine, text, count, seconds, most in session.execute(per_text):
            alarms_out[machine].by_text[text] = (int(count), float(seconds), float(most))
