"""Utilization from the stored status timeline: time per state, parts, runs, stops and alarms.

Everything here is read from ``status_samples`` (one row per change of a machine's state,
program, part counter or alarm; server/web/timeline.py), through the one classifier
(:mod:`opendnc.server.state`), per shift, day or week of the shop's calendar
(:mod:`opendnc.server.shifts`). Definitions (docs/dashboard.md#utilization):

* **time in each state**: a sample's state lasts until the machine's next sample; before a
  machine's first sample, and from a server stop to the next start, it is ``no_record``;
* **utilization** = running time within shift time / shift time (the scheduled time: what a
  shop plans to run). A shop without ``[[shifts]]`` schedules every hour;
* **utilization over recorded time** = running time / (time - no record): the same figure
  where a period is partly unrecorded or runs outside its shifts;
* **parts**: the increases of the control's part counter (a Haas's M30 counter from MDC Q500;
  a counter that goes down was reset, and its new value counts); ``None`` where the control
  reports no counter;
* **runs**: program runs that ended in the period: the part counter going up, or (without a
  counter, a TNC) the control going from running back to ready. An alarm, a lost link or a
  server stop ends a run without counting it. A run's **cycle time** is its running time
  (feed holds and stops within the run do not count);
* **stops**: stretches of 5 minutes or more in which the machine did not run (ready,
  stopped, alarm, offline or unknown, consecutive ones joined), named by their worst state
  (alarm, stopped, offline, unknown, ready); **alarms**: stretches in alarm with the control's
  text.

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

import bisect
import functools
import itertools
import logging
import threading
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from enum import StrEnum
from typing import Any, NamedTuple

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
from opendnc.server.state import State, classify_words
from opendnc.server.store.models import (
    StatusSample,
    UtcDateTime,
    UtilizationHour,
    UtilizationMark,
    UtilizationStretch,
)

__all__ = [
    "STATES",
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
    "report",
    "roll",
    "stored_state",
    "sum_safely",
    "summarize",
    "sweep",
]

log = logging.getLogger(__name__)
STATES: tuple[State, ...] = tuple(State)
STOP_MIN = 300.0  # seconds: shorter pauses are part of the work (a tool change, a part swap)
TOP_STOPS = 10
RECENT_ALARMS = 20
HOUR = timedelta(hours=1)
ROLL_MARGIN = timedelta(minutes=2)  # the recorder writes within seconds; leave it room
REWIND = timedelta(days=1)  # how far before a late sample its machine is summed again
_NOT_RUNNING = {State.READY, State.STOPPED, State.ALARM, State.OFFLINE, State.UNKNOWN}
# a stop is named by the worst state in it
_STOP_RANK = {State.READY: 0, State.UNKNOWN: 1, State.OFFLINE: 2, State.STOPPED: 3, State.ALARM: 4}
_ABORT = {State.ALARM, State.OFFLINE, State.NO_RECORD, State.UNKNOWN}
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


class Group(StrEnum):
    """What a report's periods are."""

    SHIFT = "shift"
    DAY = "day"
    WEEK = "week"


def stored_state(state: str, execution: str = "") -> State:
    """A stored sample's state in the classifier's words. Samples written before the one
    classifier said ``active`` for running, ``none`` for no record, and filed a control that
    reported no execution word as ``ready``: its execution word decides (``unknown``)."""
    if state in ("none", "no_record"):
        return State.NO_RECORD
    if state in ("active", "running"):
        return State.RUNNING
    if state == "ready":
        return classify_words(online=True, execution=execution, errors=False)
    try:
        return State(state)
    except ValueError:
        return State.UNKNOWN


class Point(NamedTuple):
    """A machine's state from ``at`` on (one stored sample). A named tuple: a year of
    samples makes millions of them."""

    at: datetime
    state: State
    program: str = ""
    part_count: int | None = None
    alarm: str = ""


@functools.lru_cache(maxsize=4096)
def _state_of(state: str, execution: str) -> State:
    return stored_state(state, execution)


def point_of(row: Any) -> Point:
    """A :class:`Point` from a ``status_samples`` row (ORM object or named row)."""
    at = row.at
    return Point(
        at if at.tzinfo else at.replace(tzinfo=UTC),
        _state_of(row.state, row.execution),
        row.program or "",
        row.part_count,
        row.alarm or "",
    )


def _point_of_sample(row: Any) -> Point:
    # a row of _SAMPLE_COLUMNS by position (named access costs more per row)
    _machine, _id, at, state, execution, program, part_count, alarm = row
    return Point(at, _state_of(state, execution), program or "", part_count, alarm or "")


@dataclass
class Figures:
    """Sums over some time: seconds per state (all of it, and within shifts), parts, runs."""

    seconds: dict[State, float] = field(default_factory=lambda: dict.fromkeys(STATES, 0.0))
    scheduled: dict[State, float] = field(default_factory=lambda: dict.fromkeys(STATES, 0.0))
    parts: int | None = None
    runs: int = 0
    cycles: int = 0  # runs whose whole running time was seen
    cycle_seconds: float = 0.0

    def add(self, other: Figures) -> None:
        """Add ``other`` into these figures."""
        for s in STATES:
            self.seconds[s] += other.seconds[s]
            self.scheduled[s] += other.scheduled[s]
        if other.parts is not None:
            self.parts = (self.parts or 0) + other.parts
        self.runs += other.runs
        self.cycles += other.cycles
        self.cycle_seconds += other.cycle_seconds

    @property
    def total(self) -> float:
        """All the time summed."""
        return sum(self.seconds.values())

    @property
    def scheduled_total(self) -> float:
        """The shift time summed."""
        return sum(self.scheduled.values())

    @property
    def recorded(self) -> float:
        """The time with a record."""
        return self.total - self.seconds[State.NO_RECORD]

    @property
    def utilization(self) -> float | None:
        """Running time within shifts / shift time, in percent; None without shift time."""
        planned = self.scheduled_total
        return 100.0 * self.scheduled[State.RUNNING] / planned if planned > 0 else None

    @property
    def utilization_recorded(self) -> float | None:
        """Running time / recorded time, in percent; None without a record."""
        recorded = self.recorded
        return 100.0 * self.seconds[State.RUNNING] / recorded if recorded > 0 else None

    @property
    def cycle_mean(self) -> float | None:
        """The mean cycle time in seconds; None without a whole run."""
        return self.cycle_seconds / self.cycles if self.cycles else None


@dataclass(frozen=True)
class Stretch:
    """A stop or an alarm of one machine; ``ongoing`` if it had not ended at the span's end."""

    kind: str  # stop, alarm
    start: datetime
    end: datetime
    state: State
    text: str = ""
    ongoing: bool = False

    @property
    def seconds(self) -> float:
        """Its length."""
        return (self.end - self.start).total_seconds()


@dataclass
class Carry:
    """What carries over from one stretch of time into the next: the part counter's last
    value, the run in progress, the stop and the alarm in progress."""

    counter: int | None = None
    run: float = 0.0  # running seconds of the run in progress
    run_known: bool = True  # False: the run began before what was read (cycle unknown)
    ran: bool = False
    stop_start: datetime | None = None
    stop_state: State = State.READY
    stop_text: str = ""
    alarm_start: datetime | None = None
    alarm_text: str = ""

    @classmethod
    def fresh(cls, point: Point | None) -> Carry:
        """The carry at a point read without its past: what it says, the rest unknown."""
        carry = cls()
        if point is None:
            return carry
        carry.counter = point.part_count
        if point.state in (State.RUNNING, State.STOPPED):
            carry.run_known = False
            carry.ran = point.state is State.RUNNING
        if point.state in _NOT_RUNNING:
            carry.stop_start, carry.stop_state = point.at, point.state
            carry.stop_text = point.alarm if point.state is State.ALARM else ""
        if point.state is State.ALARM:
            carry.alarm_start, carry.alarm_text = point.at, point.alarm
        return carry

    def as_json(self) -> dict[str, Any]:
        """For ``utilization_marks.carry``."""
        return {
            "counter": self.counter,
            "run": self.run,
            "run_known": self.run_known,
            "ran": self.ran,
            "stop_start": self.stop_start.isoformat() if self.stop_start else None,
            "stop_state": self.stop_state.value,
            "stop_text": self.stop_text,
            "alarm_start": self.alarm_start.isoformat() if self.alarm_start else None,
            "alarm_text": self.alarm_text,
        }

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> Carry:
        """From ``utilization_marks.carry``."""

        def when(value: Any) -> datetime | None:
            return datetime.fromisoformat(value) if value else None

        return cls(
            counter=data.get("counter"),
            run=float(data.get("run") or 0.0),
            run_known=bool(data.get("run_known", True)),
            ran=bool(data.get("ran", False)),
            stop_start=when(data.get("stop_start")),
            stop_state=State(data.get("stop_state") or "ready"),
            stop_text=str(data.get("stop_text") or ""),
            alarm_start=when(data.get("alarm_start")),
            alarm_text=str(data.get("alarm_text") or ""),
        )


@dataclass(frozen=True)
class Bin:
    """A piece of time summed on its own: which period it belongs to and whether it is shift
    time."""

    start: datetime
    end: datetime
    period: int | None = None
    in_shift: bool = False


def make_bins(
    periods: Sequence[Period],
    scheduled: Sequence[tuple[datetime, datetime]],
    start: datetime,
    end: datetime,
) -> list[Bin]:
    """``[start, end)`` cut at every period and shift boundary (the bins cover all of it)."""
    cuts = {start, end}
    for p in periods:
        cuts.update(t for t in (p.start, p.end) if start < t < end)
    for a, b in scheduled:
        cuts.update(t for t in (a, b) if start < t < end)
    edges = sorted(cuts)
    starts = [p.start for p in periods]
    shift_starts = [x for x, _y in scheduled]  # merged intervals, in order
    bins = []
    for a, b in itertools.pairwise(edges):
        i = bisect.bisect_right(starts, a) - 1
        while i >= 0 and periods[i].end <= a:
            i -= 1  # periods are in start order; an earlier one may still reach over a
        period = i if i >= 0 and periods[i].start <= a < periods[i].end else None
        k = bisect.bisect_right(shift_starts, a) - 1
        in_shift = k >= 0 and scheduled[k][0] <= a < scheduled[k][1]
        bins.append(Bin(a, b, period, in_shift))
    return bins


def sweep(
    points: Sequence[Point],
    start: datetime,
    end: datetime,
    bins: Sequence[Bin],
    carry: Carry,
    stretches: list[Stretch] | None = None,
) -> list[Figures]:
    """Sum ``points`` (one machine's, in time order, from the one in force at ``start``)
    over ``[start, end)`` into one :class:`Figures` per bin. ``carry`` comes in as at
    ``start`` and goes out as at ``end``; finished stops and alarms go to ``stretches``."""
    figures = [Figures() for _ in bins]
    ends = [b.end for b in bins]
    i = 0
    while i + 1 < len(points) and points[i + 1].at <= start:
        i += 1
    if not points or points[0].at > start:
        current = State.NO_RECORD  # before the machine's first sample
        nxt = 0
    else:
        current = points[i].state
        nxt = i + 1
        if points[i].at == start and (i == 0 or points[i - 1].at < start):
            nxt = i  # a sample exactly at the start changes the state there
            current = points[i - 1].state if i > 0 else State.NO_RECORD
    counting = carry.counter is not None or any(p.part_count is not None for p in points)
    t = start
    while t < end:
        if nxt < len(points) and points[nxt].at <= t:
            current = _transition(points[nxt], carry, figures, bins, ends, stretches)
            nxt += 1
            continue
        until = min(points[nxt].at, end) if nxt < len(points) else end
        if until > t:
            _spend(t, until, current, figures, bins, ends, counting)
            if current is State.RUNNING:
                carry.run += (until - t).total_seconds()
                carry.ran = True
        t = until
    return figures


def _bin_at(at: datetime, ends: list[datetime]) -> int:
    return bisect.bisect_right(ends, at)


def _spend(
    a: datetime,
    b: datetime,
    state: State,
    figures: list[Figures],
    bins: Sequence[Bin],
    ends: list[datetime],
    counting: bool,
) -> None:
    j = _bin_at(a, ends)
    while j < len(bins) and bins[j].start < b:
        lo, hi = max(a, bins[j].start), min(b, bins[j].end)
        if hi > lo:
            seconds = (hi - lo).total_seconds()
            fig = figures[j]
            fig.seconds[state] += seconds
            if bins[j].in_shift:
                fig.scheduled[state] += seconds
            if counting and fig.parts is None:
                fig.parts = 0
        j += 1


def _transition(
    p: Point,
    carry: Carry,
    figures: list[Figures],
    bins: Sequence[Bin],
    ends: list[datetime],
    stretches: list[Stretch] | None,
) -> State:
    j = _bin_at(p.at, ends)
    # a change outside the bins (read only for what it carries) counts nowhere
    fig = figures[j] if j < len(figures) and bins[j].start <= p.at else None
    completed = False
    if p.part_count is not None:
        if carry.counter is not None and p.part_count != carry.counter:
            # a counter that went down was reset: its new value is what was made since
            gained = p.part_count - carry.counter if p.part_count > carry.counter else p.part_count
            if gained > 0:
                completed = True
                if fig is not None:
                    fig.parts = (fig.parts or 0) + gained
        carry.counter = p.part_count
    ready_ends_run = carry.counter is None and p.state is State.READY and carry.ran
    if ((completed and (carry.ran or carry.run > 0)) or ready_ends_run) and fig is not None:
        fig.runs += 1
        if carry.run_known:
            fig.cycles += 1
            fig.cycle_seconds += carry.run
    if completed or ready_ends_run or p.state in _ABORT or p.state is State.READY:
        carry.run, carry.run_known, carry.ran = 0.0, True, False
    # alarms: one stretch per alarm text
    if carry.alarm_start is not None and (
        p.state is not State.ALARM or p.alarm != carry.alarm_text
    ):
        if stretches is not None:
            stretches.append(
                Stretch("alarm", carry.alarm_start, p.at, State.ALARM, carry.alarm_text)
            )
        carry.alarm_start, carry.alarm_text = None, ""
    if p.state is State.ALARM and carry.alarm_start is None:
        carry.alarm_start, carry.alarm_text = p.at, p.alarm
    # stops: consecutive states that are not running, joined
    if p.state in _NOT_RUNNING:
        if carry.stop_start is None:
            carry.stop_start, carry.stop_state, carry.stop_text = p.at, p.state, ""
        elif _STOP_RANK[p.state] > _STOP_RANK[carry.stop_state]:
            carry.stop_state = p.state
        if p.state is State.ALARM and not carry.stop_text:
            carry.stop_text = p.alarm
    elif carry.stop_start is not None:
        if stretches is not None and (p.at - carry.stop_start).total_seconds() >= STOP_MIN:
            stretches.append(
                Stretch("stop", carry.stop_start, p.at, carry.stop_state, carry.stop_text)
            )
        carry.stop_start, carry.stop_text = None, ""
    return p.state


def open_stretches(carry: Carry, end: datetime) -> list[Stretch]:
    """The stop and the alarm still in progress at ``end``."""
    out = []
    if carry.stop_start is not None and (end - carry.stop_start).total_seconds() >= STOP_MIN:
        out.append(
            Stretch("stop", carry.stop_start, end, carry.stop_state, carry.stop_text, ongoing=True)
        )
    if carry.alarm_start is not None:
        out.append(
            Stretch("alarm", carry.alarm_start, end, State.ALARM, carry.alarm_text, ongoing=True)
        )
    return out


# -- summing finished hours ------------------------------------------------------------------


def floor_hour(at: datetime) -> datetime:
    """The start of ``at``'s UTC hour."""
    at = at.astimezone(UTC)
    return at.replace(minute=0, second=0, microsecond=0)


def ceil_hour(at: datetime) -> datetime:
    """The first full UTC hour at or after ``at``."""
    floor = floor_hour(at)
    return floor if floor == at else floor + HOUR


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
            out[row[0]].append(_point_of_sample(row))
        rows = session.execute(
            select(*_SAMPLE_COLUMNS)
            .where(StatusSample.machine.in_(chunk), StatusSample.at >= start, StatusSample.at < end)
            .order_by(StatusSample.machine, StatusSample.at, StatusSample.id)
        )
        for row in rows:
            out[row[0]].append(_point_of_sample(row))
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


# -- reports ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class AlarmSummary:
    """One alarm text of one machine over the span."""

    text: str
    count: int
    seconds: float
    longest: float


@dataclass
class MachineReport:
    """One machine over the span: totals, per period, its longest stops and its alarms."""

    machine: str
    totals: Figures
    periods: list[Figures]
    stops: list[Stretch]
    alarms: list[AlarmSummary]
    recent_alarms: list[Stretch]


@dataclass
class Report:
    """Utilization of some machines over ``[start, end)``, per ``group`` period."""

    start: datetime
    end: datetime
    group: Group
    calendar: Calendar
    periods: list[Period]
    machines: list[MachineReport]


def periods_of(calendar: Calendar, group: Group, start: datetime, end: datetime) -> list[Period]:
    """The ``group`` periods of ``[start, end)``, cut to it."""
    make = {
        Group.SHIFT: calendar.shift_periods,
        Group.DAY: calendar.day_periods,
        Group.WEEK: calendar.week_periods,
    }[group]
    return [Period(p.key, max(p.start, start), min(p.end, end), p.shift) for p in make(start, end)]


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
        _machine_report(m, totals[m], per_period[m], stretches[m], start, end) for m in machines
    ]
    return Report(start, end, group, calendar, periods, reports)


def equal_periods(start: datetime, end: datetime, step: timedelta) -> list[Period]:
    """``[start, end)`` in equal buckets of ``step`` (the last one cut), for :func:`buckets`."""
    out = []
    at = start
    while at < end:
        until = min(at + step, end)
        out.append(Period(at.isoformat(), at, until))
        at = until
    return out


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
                for x in _within(bins, a, b)
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
                sweep_from = min(a, _utc(first)) if first is not None else a
                carry = Carry()
                points = read_points(session, machine, sweep_from, b)
            elif is_tail and mark is not None and mark.until == a:
                points = read[machine]
                carry = Carry.from_json(mark.carry)
            else:
                points = read[machine]
                carry = Carry.fresh(_in_force(points, a))
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
        points = [_point_of_sample(r) for r in rows]
        if not points:
            out += open_stretches(carry, max(now, at))
            return
        _follow(points, carry, out)
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
            later[row[0]].append(_point_of_sample(row))
    for machine in names:
        carry, at = open_[machine]
        points = sorted(later[machine], key=lambda p: p.at)
        _follow(points, carry, out[machine])
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


def _follow(points: Sequence[Point], carry: Carry, out: list[Stretch]) -> None:
    """Feed ``points`` to ``carry`` until its stop and alarm are closed (what they finish
    goes to ``out``; nothing is counted)."""
    for p in points:
        if carry.stop_start is None and carry.alarm_start is None:
            return
        _transition(p, carry, [], [], [], out)


def sum_safely(session: Session, machines: Sequence[str], now: datetime) -> None:
    """:func:`roll` in a savepoint: if another server sharing the database summed the same
    hours just now, its sums stand and this one's are dropped."""
    try:
        with session.begin_nested():
            roll(session, machines, now)
    except IntegrityError:
        log.info("utilization: another server summed these hours first")


def _within(bins: Sequence[Bin], a: datetime, b: datetime) -> Sequence[Bin]:
    """The bins that overlap ``[a, b)`` (bins are consecutive)."""
    ends = [x.end for x in bins]
    first = bisect.bisect_right(ends, a)
    last = first
    while last < len(bins) and bins[last].start < b:
        last += 1
    return bins[first:last]


def _in_force(points: Sequence[Point], at: datetime) -> Point | None:
    found = None
    for p in points:
        if p.at <= at:
            found = p
        else:
            break
    return found


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
        j = _bin_at(hour, ends)
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
                    Stretch(r.kind, _utc(r.start), _utc(r.end), State(r.state), r.text)
                )


def _utc(at: datetime) -> datetime:
    return at if at.tzinfo else at.replace(tzinfo=UTC)


def _machine_report(
    machine: str,
    totals: Figures,
    periods: list[Figures],
    found: list[Stretch],
    start: datetime,
    end: datetime,
) -> MachineReport:
    stops = sorted(
        (s for s in found if s.kind == "stop" and s.end > start and s.start < end),
        key=lambda s: (-s.seconds, s.start),
    )[:TOP_STOPS]
    alarms = [s for s in found if s.kind == "alarm" and s.end > start and s.start < end]
    by_text: dict[str, list[Stretch]] = {}
    for a in alarms:
        by_text.setdefault(a.text, []).append(a)
    summary = sorted(
        (
            AlarmSummary(
                text, len(items), sum(a.seconds for a in items), max(a.seconds for a in items)
            )
            for text, items in by_text.items()
        ),
        key=lambda a: (-a.seconds, a.text),
    )
    recent = sorted(alarms, key=lambda a: a.start, reverse=True)[:RECENT_ALARMS]
    return MachineReport(machine, totals, periods, stops, summary, recent)


def summarize(
    machine: str,
    points: Sequence[Point],
    calendar: Calendar,
    group: Group,
    start: datetime,
    end: datetime,
    *,
    now: datetime | None = None,
) -> tuple[list[Period], MachineReport]:
    """One machine's report from its points alone (no database): the in-force point at
    ``start`` and the ones after, in time order (later ones finish the stop or alarm open
    at ``end``; one still open lasts until ``now``, by default ``end``). What :func:`report`
    computes from the samples."""
    start, end = start.astimezone(UTC), end.astimezone(UTC)
    periods = periods_of(calendar, group, start, end)
    bins = make_bins(periods, calendar.scheduled(start, end), start, end)
    inside = [p for p in points if p.at < end]
    # from the first point on, so what carries into the span is known (a point before the
    # start with nothing before it is read as where the machine's record begins)
    sweep_from = min(start, inside[0].at) if inside else start
    carry = Carry()
    found: list[Stretch] = []
    figures = sweep(inside, sweep_from, end, bins, carry, found)
    _follow([p for p in points if p.at >= end], carry, found)
    if carry.stop_start is not None or carry.alarm_start is not None:
        found += open_stretches(carry, max(now or end, points[-1].at if points else end))
    totals = Figures()
    per_period = [Figures() for _ in periods]
    for b, f in zip(bins, figures, strict=True):
        totals.add(f)
        if b.period is not None:
            per_period[b.period].add(f)
    return periods, _machine_report(machine, totals, per_period, found, start, end)
