"""The arithmetic of utilization: one machine's status timeline swept into sums per piece of
time (seconds per state, shift time, parts, runs and cycles), its stops and its alarms.

No database here: :mod:`opendnc.server.utilization.collect` reads the samples and the summed
hours and hands the points to :func:`sweep`; :func:`summarize` does the whole of it for one
machine's points (the tests' reference). States come from the one classifier
(:mod:`opendnc.server.core.state`). Definitions (docs/dashboard.md#utilization):

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
"""

from __future__ import annotations

import bisect
import functools
import itertools
from collections.abc import Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from enum import StrEnum
from typing import Any, NamedTuple

from opendnc.server.config.downtime import STOP_MIN
from opendnc.server.core.shifts import Calendar, Period
from opendnc.server.core.state import State, from_stored

__all__ = [
    "HOUR",
    "RECENT_ALARMS",
    "STATES",
    "STOP_MIN",
    "TOP_STOPS",
    "AlarmSummary",
    "Bin",
    "Carry",
    "Figures",
    "Group",
    "MachineReport",
    "Point",
    "ProgramRuns",
    "Stretch",
    "SummedAlarms",
    "as_utc",
    "bin_at",
    "bins_within",
    "ceil_hour",
    "equal_periods",
    "floor_hour",
    "follow",
    "in_force",
    "machine_report",
    "make_bins",
    "open_stretches",
    "periods_of",
    "point_of",
    "point_of_columns",
    "program_key",
    "summarize",
    "sweep",
]


STATES: tuple[State, ...] = tuple(State)


TOP_STOPS = 10


RECENT_ALARMS = 20


HOUR = timedelta(hours=1)


_NOT_RUNNING = {State.READY, State.STOPPED, State.ALARM, State.OFFLINE, State.UNKNOWN}


# a stop is named by the worst state in it
_STOP_RANK = {State.READY: 0, State.UNKNOWN: 1, State.OFFLINE: 2, State.STOPPED: 3, State.ALARM: 4}


_ABORT = {State.ALARM, State.OFFLINE, State.NO_RECORD, State.UNKNOWN}


class Group(StrEnum):
    """What a report's periods are."""

    SHIFT = "shift"
    DAY = "day"
    WEEK = "week"


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
    return from_stored(state, execution)


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


def point_of_columns(row: Any) -> Point:
    """A :class:`Point` from a row of (machine, id, at, state, execution, program, part
    count, alarm), by position: named access costs more, over millions of rows."""
    _machine, _id, at, state, execution, program, part_count, alarm = row
    return Point(at, _state_of(state, execution), program or "", part_count, alarm or "")


@functools.lru_cache(maxsize=4096)
def program_key(name: str) -> str:
    """A program name on a control as the library's key: without its folder, case-folded
    (``TNC:\\nc_prog\\POCKET.H`` and ``pocket.h`` are one)."""
    return name.replace("\\", "/").rsplit("/", 1)[-1].strip().lower()


@dataclass
class ProgramRuns:
    """Runs of one program ended in a piece of time, and the running seconds of the program
    in it (what OEE's performance reads)."""

    runs: int = 0
    seconds: float = 0.0


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
        # (a year's report adds tens of thousands of these: skip the zeros)
        mine = self.seconds
        for s, value in other.seconds.items():
            if value:
                mine[s] += value
        mine = self.scheduled
        for s, value in other.scheduled.items():
            if value:
                mine[s] += value
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
    # the program running (its name as the control gave it): runs and running time count
    # for it (OEE's performance); a run ends counted for the program it ran
    program: str = ""

    @classmethod
    def fresh(cls, point: Point | None) -> Carry:
        """The carry at a point read without its past: what it says, the rest unknown."""
        carry = cls()
        if point is None:
            return carry
        carry.counter = point.part_count
        carry.program = point.program
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
            "program": self.program,
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
            program=str(data.get("program") or ""),
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
    programs: list[dict[str, ProgramRuns]] | None = None,
) -> list[Figures]:
    """Sum ``points`` (one machine's, in time order, from the one in force at ``start``)
    over ``[start, end)`` into one :class:`Figures` per bin. ``carry`` comes in as at
    ``start`` and goes out as at ``end``; finished stops and alarms go to ``stretches``;
    with ``programs`` (a dict per bin), the runs and running seconds per program (by
    :func:`program_key`) too."""
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
            p = points[nxt]
            if programs is None:
                current = _transition(p, carry, figures, bins, ends, stretches)
            else:
                current = _transition_per_program(
                    p, carry, figures, bins, ends, stretches, programs
                )
            nxt += 1
            continue
        until = min(points[nxt].at, end) if nxt < len(points) else end
        if until > t:
            _spend(t, until, current, figures, bins, ends, counting)
            if current is State.RUNNING:
                carry.run += (until - t).total_seconds()
                carry.ran = True
                if programs is not None:
                    _spend_program(t, until, program_key(carry.program), programs, bins, ends)
        t = until
    return figures


def _transition_per_program(
    p: Point,
    carry: Carry,
    figures: list[Figures],
    bins: Sequence[Bin],
    ends: list[datetime],
    stretches: list[Stretch] | None,
    programs: list[dict[str, ProgramRuns]],
) -> State:
    """:func:`_transition`, the run it ends (if any) counted for the program that ran."""
    j = bin_at(p.at, ends)
    inside = j < len(figures) and bins[j].start <= p.at
    before = figures[j].runs if inside else 0
    ran = carry.program
    state = _transition(p, carry, figures, bins, ends, stretches)
    if inside and figures[j].runs > before:
        held = programs[j].setdefault(program_key(ran), ProgramRuns())
        held.runs += figures[j].runs - before
    return state


def _spend_program(
    a: datetime,
    b: datetime,
    program: str,
    programs: list[dict[str, ProgramRuns]],
    bins: Sequence[Bin],
    ends: list[datetime],
) -> None:
    """Add the running seconds of ``[a, b)`` to ``program`` in the bins they fall in."""
    j = bin_at(a, ends)
    while j < len(bins) and bins[j].start < b:
        lo, hi = max(a, bins[j].start), min(b, bins[j].end)
        if hi > lo:
            held = programs[j].setdefault(program, ProgramRuns())
            held.seconds += (hi - lo).total_seconds()
        j += 1


def bin_at(at: datetime, ends: list[datetime]) -> int:
    """The index of the bin (by the bins' ``ends``) that holds ``at``."""
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
    j = bin_at(a, ends)
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
    j = bin_at(p.at, ends)
    # a change outside the bins (read only for what it carries) counts nowhere
    fig = figures[j] if j < len(figures) and bins[j].start <= p.at else None
    completed = _count_parts(p, carry, fig)
    _count_run(p, carry, fig, completed)
    _follow_alarm(p, carry, stretches)
    _follow_stop(p, carry, stretches)
    if p.program and p.state is State.RUNNING:
        carry.program = p.program  # (what runs from here on; a run that ended is counted)
    return p.state


def _count_parts(p: Point, carry: Carry, fig: Figures | None) -> bool:
    """Add the parts the counter gained at ``p`` to ``fig``; whether it gained any."""
    if p.part_count is None:
        return False
    completed = False
    if carry.counter is not None and p.part_count != carry.counter:
        # a counter that went down was reset: its new value is what was made since
        gained = p.part_count - carry.counter if p.part_count > carry.counter else p.part_count
        if gained > 0:
            completed = True
            if fig is not None:
                fig.parts = (fig.parts or 0) + gained
    carry.counter = p.part_count
    return completed


def _count_run(p: Point, carry: Carry, fig: Figures | None, completed: bool) -> None:
    """A run ends at ``p`` when the counter rose after running, or, without a counter, when
    running went back to ready; a stop that aborts it, or ready, starts the next afresh."""
    ready_ends_run = carry.counter is None and p.state is State.READY and carry.ran
    if ((completed and (carry.ran or carry.run > 0)) or ready_ends_run) and fig is not None:
        fig.runs += 1
        if carry.run_known:
            fig.cycles += 1
            fig.cycle_seconds += carry.run
    if completed or ready_ends_run or p.state in _ABORT or p.state is State.READY:
        carry.run, carry.run_known, carry.ran = 0.0, True, False


def _follow_alarm(p: Point, carry: Carry, stretches: list[Stretch] | None) -> None:
    """Alarms: one stretch per alarm text."""
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


def _follow_stop(p: Point, carry: Carry, stretches: list[Stretch] | None) -> None:
    """Stops: consecutive states that are not running, joined, named by the worst of them."""
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


def floor_hour(at: datetime) -> datetime:
    """The start of ``at``'s UTC hour."""
    at = at.astimezone(UTC)
    return at.replace(minute=0, second=0, microsecond=0)


def ceil_hour(at: datetime) -> datetime:
    """The first full UTC hour at or after ``at``."""
    floor = floor_hour(at)
    return floor if floor == at else floor + HOUR


@dataclass(frozen=True)
class AlarmSummary:
    """One alarm text of one machine over the span."""

    text: str
    count: int
    seconds: float
    longest: float


@dataclass
class SummedAlarms:
    """Stored alarms of one machine summed in the database: per text (count, seconds,
    longest), and the newest ones (at most :data:`RECENT_ALARMS`)."""

    by_text: dict[str, tuple[int, float, float]] = field(default_factory=dict)
    recent: list[Stretch] = field(default_factory=list)


@dataclass
class MachineReport:
    """One machine over the span: totals, per period, its longest stops and its alarms."""

    machine: str
    totals: Figures
    periods: list[Figures]
    stops: list[Stretch]
    alarms: list[AlarmSummary]
    recent_alarms: list[Stretch]


def periods_of(calendar: Calendar, group: Group, start: datetime, end: datetime) -> list[Period]:
    """The ``group`` periods of ``[start, end)``, cut to it."""
    make = {
        Group.SHIFT: calendar.shift_periods,
        Group.DAY: calendar.day_periods,
        Group.WEEK: calendar.week_periods,
    }[group]
    return [Period(p.key, max(p.start, start), min(p.end, end), p.shift) for p in make(start, end)]


def equal_periods(start: datetime, end: datetime, step: timedelta) -> list[Period]:
    """``[start, end)`` in equal buckets of ``step`` (the last one cut), for :func:`buckets`."""
    out = []
    at = start
    while at < end:
        until = min(at + step, end)
        out.append(Period(at.isoformat(), at, until))
        at = until
    return out


def follow(points: Sequence[Point], carry: Carry, out: list[Stretch]) -> None:
    """Feed ``points`` to ``carry`` until its stop and alarm are closed (what they finish
    goes to ``out``; nothing is counted)."""
    for p in points:
        if carry.stop_start is None and carry.alarm_start is None:
            return
        _transition(p, carry, [], [], [], out)


def bins_within(bins: Sequence[Bin], a: datetime, b: datetime) -> Sequence[Bin]:
    """The bins that overlap ``[a, b)`` (bins are consecutive)."""
    ends = [x.end for x in bins]
    first = bisect.bisect_right(ends, a)
    last = first
    while last < len(bins) and bins[last].start < b:
        last += 1
    return bins[first:last]


def in_force(points: Sequence[Point], at: datetime) -> Point | None:
    """The point whose state holds at ``at`` (points in time order), or None."""
    found = None
    for p in points:
        if p.at <= at:
            found = p
        else:
            break
    return found


def as_utc(at: datetime) -> datetime:
    """``at`` with UTC attached where the database gave it without a zone (SQLite)."""
    return at if at.tzinfo else at.replace(tzinfo=UTC)


def machine_report(
    machine: str,
    totals: Figures,
    periods: list[Figures],
    found: list[Stretch],
    start: datetime,
    end: datetime,
    summed: SummedAlarms | None = None,
) -> MachineReport:
    """One machine's report from its sums and the stops and alarms found (and those
    ``summed`` in the database): the 10 longest stops and the alarms by text that overlap
    ``[start, end)``, the newest alarms."""
    stops = sorted(
        (s for s in found if s.kind == "stop" and s.end > start and s.start < end),
        key=lambda s: (-s.seconds, s.start),
    )[:TOP_STOPS]
    alarms = [s for s in found if s.kind == "alarm" and s.end > start and s.start < end]
    by_text: dict[str, tuple[int, float, float]] = dict(summed.by_text) if summed else {}
    for a in alarms:
        count, seconds, longest = by_text.get(a.text, (0, 0.0, 0.0))
        by_text[a.text] = (count + 1, seconds + a.seconds, max(longest, a.seconds))
    summary = sorted(
        (AlarmSummary(text, *figures) for text, figures in by_text.items()),
        key=lambda a: (-a.seconds, a.text),
    )
    if summed:
        alarms += summed.recent
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
    if now is not None:  # nothing counts after now (as in :func:`report`)
        end = min(end, max(start, now))
        points = [p for p in points if p.at < now]
    bins = make_bins(periods, calendar.scheduled(start, end), start, end)
    inside = [p for p in points if p.at < end]
    # from the first point on, so what carries into the span is known (a point before the
    # start with nothing before it is read as where the machine's record begins)
    sweep_from = min(start, inside[0].at) if inside else start
    carry = Carry()
    found: list[Stretch] = []
    figures = sweep(inside, sweep_from, end, bins, carry, found)
    follow([p for p in points if p.at >= end], carry, found)
    if carry.stop_start is not None or carry.alarm_start is not None:
        found += open_stretches(carry, max(now or end, points[-1].at if points else end))
    totals = Figures()
    per_period = [Figures() for _ in periods]
    for b, f in zip(bins, figures, strict=True):
        totals.add(f)
        if b.period is not None:
            per_period[b.period].add(f)
    return periods, machine_report(machine, totals, per_period, found, start, end)
