"""OEE per machine and period, parts against a goal, and the stops with their reasons: what
a supervisor reads at a glance, next to utilization (docs/dashboard.md#oee).

In our words (ISO 22400's terms):

* **planned time**: the shift time of the period (``[[shifts]]``; a shop without shifts
  plans every hour), up to now;
* **availability** = running time within shifts / planned time: the utilization figure
  itself (one function, :attr:`.sums.Figures.utilization`);
* **performance** = ideal cycle time x runs / running time, over the programs with a
  standard time: each run of a program counts its standard, and its running seconds are the
  time those runs took. A program without a standard is left out (and named);
* **quality** = good parts / parts made. Parts made are the good and scrapped parts
  reported (:class:`~opendnc.server.store.models.PartReport`) when good ones are, else the
  control's part counter, else the runs; good = made - scrapped;
* **OEE** = availability x performance x quality;
* **goal**: the parts a supervisor set for the machine (``[goals]``, per shift or per day,
  :mod:`opendnc.server.config.goals`), else the parts the planned time makes at the standard
  pace (planned time / the mean standard time of what ran); always for the whole period,
  and **expected** the goal of the period's planned time up to now (the same pace).

The standard time of a program version is the one a supervisor set, else the check's
estimate (``cycle_time_s`` of :mod:`opendnc.nccheck`). A program on the control is the
library's program of that name (case-folded, without its folder), at its newest released
version (else its newest). Runs and stops are read from the status samples, which are kept
``[server] timeline_retention_days``: performance needs them; older stops come from the
summed stops.
"""

from __future__ import annotations

import bisect
import math
from collections import defaultdict
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from datetime import UTC, date, datetime, time, timedelta
from typing import Any

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from opendnc.server.config.downtime import NO_REASON
from opendnc.server.config.goals import Goal, GoalsConfig
from opendnc.server.core.gc_pause import paused
from opendnc.server.core.shifts import Period
from opendnc.server.core.state import State
from opendnc.server.store.models import (
    PartReport,
    Program,
    ProgramState,
    ProgramVersion,
    StandardTime,
    VersionCheck,
)
from opendnc.server.utilization.collect import (
    LONGEST_READ,
    Report,
    longest_stops,
    marks_of,
    plan_hours,
    program_sums,
    read_many,
    read_points,
)
from opendnc.server.utilization.downtime import (
    ParetoRow,
    StopWithReason,
    order_pareto,
    reasons_for,
    with_reasons,
)
from opendnc.server.utilization.lost import Lost, covered_days, lost_of, stops_with_reasons
from opendnc.server.utilization.sums import (
    Bin,
    Carry,
    Figures,
    ProgramRuns,
    Stretch,
    as_utc,
    bins_within,
    ceil_hour,
    in_force,
    make_bins,
    open_stretches,
    program_key,
    sweep,
)

__all__ = [
    "LOOK_BACK",
    "FloorReport",
    "MachineFloor",
    "Oee",
    "ProgramRuns",
    "Standard",
    "floor_of",
    "oee_of",
    "program_key",
    "standards_for",
]

LOOK_BACK = timedelta(hours=12)  # samples read before a span: where its first stop began


@dataclass(frozen=True)
class Standard:
    """The standard cycle time of the version a program name stands for."""

    program: str
    version_id: int | None = None
    version: int | None = None
    seconds: float | None = None
    source: str = ""  # set (by a supervisor), estimate (the check's), "" (none)
    estimate: float | None = None  # the check's estimate, set or not


@dataclass(frozen=True)
class Oee:
    """OEE and its factors for one machine over one period (fractions 0..1, None where a
    factor has nothing to stand on)."""

    planned: float
    running: float  # running time within the planned time
    availability: float | None
    ideal: float  # standard seconds of the runs of programs with a standard
    timed: float  # the running seconds those runs took
    performance: float | None
    made: int | None
    good: int | None
    scrap: int
    quality: float | None
    oee: float | None
    goal: int | None  # the whole period's
    missing: tuple[str, ...] = ()  # programs that ran without a standard time
    expected: int | None = None  # the goal's part of the period up to now


def oee_of(
    figures: Figures,
    runs: dict[str, ProgramRuns],
    standards: dict[str, Standard],
    good: int = 0,
    scrap: int = 0,
    *,
    planned_full: float | None = None,
    target: tuple[float, float] | None = None,
) -> Oee:
    """The OEE of one machine and period from its utilization figures, its runs per program,
    the standards and the parts reported (docs/dashboard.md#oee). ``planned_full`` is the
    whole period's planned time (the figures' up to now by default); ``target`` the
    configured goal of the whole period and of it up to now (``[goals]``)."""
    planned = figures.scheduled_total
    running = figures.scheduled[State.RUNNING]
    utilization = figures.utilization  # the same figure as the utilization column
    availability = None if utilization is None else utilization / 100.0
    ideal = timed = 0.0
    counted = 0
    missing = []
    for program, r in sorted(runs.items()):
        std = standards.get(program)
        if std is None or std.seconds is None:
            if r.runs:
                missing.append(program or "(no name)")
            continue
        ideal += std.seconds * r.runs
        timed += r.seconds
        counted += r.runs
    performance = ideal / timed if timed > 0 and ideal > 0 else None
    if good > 0:
        made: int | None = good + scrap
    elif figures.parts is not None:
        made = figures.parts
    else:
        made = figures.runs
    good_out = None if made is None else max(made - scrap, 0)
    quality = good_out / made if made and good_out is not None else None
    oee = (
        availability * performance * quality
        if availability is not None and performance is not None and quality is not None
        else None
    )
    goal, expected = _goal(planned, planned_full, counted, ideal, target)
    return Oee(
        planned=planned,
        running=running,
        availability=availability,
        ideal=ideal,
        timed=timed,
        performance=performance,
        made=made,
        good=good_out,
        scrap=scrap,
        quality=quality,
        oee=oee,
        goal=goal,
        missing=tuple(missing),
        expected=expected,
    )


def _goal(
    planned: float,
    planned_full: float | None,
    counted: int,
    ideal: float,
    target: tuple[float, float] | None,
) -> tuple[int | None, int | None]:
    """The goal of the whole period and the part of it expected by now (whole parts: the
    goal rounded, what is expected by now only once a part is due in full)."""
    if target is not None:
        full, so_far = target
        return round(full), math.floor(so_far + 1e-9)
    if ideal <= 0 or planned <= 0:
        return None, None
    pace = counted / ideal  # parts per planned second at the standard pace
    whole = planned if planned_full is None else max(planned_full, planned)
    return math.floor(whole * pace + 1e-9), math.floor(planned * pace + 1e-9)


def standards_for(session: Session, names: Iterable[str]) -> dict[str, Standard]:
    """The standard of each program name (by :func:`program_key`): the set one of the
    version it stands for, else that version's check estimate."""
    keys = {program_key(n) for n in names if n}
    out: dict[str, Standard] = {}
    if not keys:
        return out
    rows = session.execute(
        select(Program.name, ProgramVersion.id, ProgramVersion.number, ProgramVersion.state)
        .join(ProgramVersion, ProgramVersion.program_id == Program.id)
        .where(func.lower(Program.name).in_(keys))
        .order_by(ProgramVersion.number)
    ).all()
    chosen: dict[str, tuple[str, int, int, bool]] = {}
    for name, vid, number, state in rows:
        key = name.lower()
        released = state == ProgramState.RELEASED
        held = chosen.get(key)
        if held is None or released or not held[3]:
            chosen[key] = (name, vid, number, released)
    ids = [c[1] for c in chosen.values()]
    set_times = {
        r.version_id: r.seconds
        for r in session.scalars(select(StandardTime).where(StandardTime.version_id.in_(ids)))
    }
    estimates: dict[int, float] = {}
    for check in session.scalars(
        select(VersionCheck).where(VersionCheck.version_id.in_(ids)).order_by(VersionCheck.id)
    ):
        seconds = (check.facts or {}).get("cycle_time_s")
        if not isinstance(seconds, int | float) or seconds <= 0:
            continue
        # the check of the text alone ("" limits) first: it is every machine's
        if check.version_id not in estimates or check.limits == "":
            estimates[check.version_id] = float(seconds)
    for key, (name, vid, number, _released) in chosen.items():
        guess = estimates.get(vid)
        if vid in set_times:
            out[key] = Standard(name, vid, number, set_times[vid], "set", guess)
        elif guess is not None:
            out[key] = Standard(name, vid, number, guess, "estimate", guess)
        else:
            out[key] = Standard(name, vid, number)
    return out


@dataclass
class MachineFloor:
    """One machine's OEE in total and per period, and its stops with their reasons."""

    machine: str
    totals: Oee
    periods: list[Oee]
    stops: list[StopWithReason]
    runs: dict[str, ProgramRuns] = field(default_factory=dict)


@dataclass
class FloorReport:
    """OEE and downtime of a :class:`~.collect.Report`'s machines over its span."""

    machines: list[MachineFloor]
    pareto: list[ParetoRow]
    standards: dict[str, Standard]
    covered_from: datetime  # runs (performance) are read from here on
    reasons: tuple[str, ...] = ()  # the configured reasons, in their order
    lost: Lost = field(default_factory=Lost)  # every stop's time per reason
    period_index: dict[datetime, int] = field(default_factory=dict)  # by a period's start

    def lost_by_reason(self, machine: str, period: Period | None = None) -> dict[str, float]:
        """Seconds of the machine's stops per reason (those that began in ``period``, or
        all), every configured reason and :data:`.downtime.NO_REASON` present."""
        out = dict.fromkeys([*self.reasons, NO_REASON], 0.0)
        if period is None:
            for name, (_stops, seconds) in self.lost.totals.get(machine, {}).items():
                out[name] = out.get(name, 0.0) + seconds
            return out
        i = self.period_index.get(period.start)
        if i is None:
            return out
        for name, seconds in self.lost.periods.get(machine, {}).get(i, {}).items():
            out[name] = out.get(name, 0.0) + seconds
        return out

    # (the answer asks for a machine once per period: 10 000 times for a year by week)
    _by_name: dict[str, MachineFloor] = field(default_factory=dict, init=False, repr=False)

    def __post_init__(self) -> None:
        self._by_name = {m.machine: m for m in self.machines}

    def of(self, machine: str) -> MachineFloor | None:
        """The machine's figures."""
        return self._by_name.get(machine)


LIST_ALL = timedelta(days=2, hours=1)  # up to this span every stop is listed (to pick for)
LISTED = LONGEST_READ - 1  # over a longer span, each machine's longest stops (20)


def floor_of(
    session: Session,
    report: Report,
    retention: timedelta,
    reasons: Sequence[str] = (),
    now: datetime | None = None,
    goals: GoalsConfig | None = None,
    *,
    use_sums: bool = True,
) -> FloorReport:
    """OEE, parts, stops and reasons for ``report``'s machines, periods and span (the goals
    of ``[goals]`` where a machine has one): the runs per program from the summed hours and
    the samples after them (``use_sums=False``: from every sample of each machine, the
    reference the sums are tested against)."""
    # (the stops, their reasons and an OEE per machine and period: tens of thousands of
    # objects, which the collector would otherwise walk with the whole process)
    with paused():
        return _floor(session, report, retention, reasons, now, goals, use_sums)


def _floor(
    session: Session,
    report: Report,
    retention: timedelta,
    reasons: Sequence[str],
    now: datetime | None,
    goals: GoalsConfig | None,
    use_sums: bool,
) -> FloorReport:
    now = now or datetime.now(UTC)
    start, until = report.start, report.until or report.end
    # runs are counted from the first whole hour of the kept samples (the hours sum them per
    # program from there: a cut hour would need what carried into it); stops are summed
    # with the hours
    covered = max(start, ceil_hour(now - retention))
    periods = report.periods
    names = [m.machine for m in report.machines]
    bins = make_bins(periods, [], covered, until) if until > covered else []
    parts = _parts(session, names, periods, start, until)
    follow = _runs_summed if use_sums else _runs_of_every_sample
    per_machine = follow(session, names, bins, len(periods), covered, until)
    programs = {k for runs, _found in per_machine.values() for r in runs for k in r}
    standards = standards_for(session, programs)
    stops, days = _stops(session, report, names, {m: f for m, (_r, f) in per_machine.items()})
    lost = lost_of(
        session, report.calendar, names, periods, report.group, start, until, days, stops
    )
    listed = stops if days is None else _longest(session, report, names, stops)
    machines = []
    planned: dict[tuple[datetime, datetime], float] = {}
    for m in report.machines:
        by_period, _found = per_machine[m.machine]
        total_runs: dict[str, ProgramRuns] = {}
        for r in by_period:
            _merge(total_runs, r)
        good_scrap = parts.get(m.machine, {})
        total_good = sum(g for g, _s in good_scrap.values())
        total_scrap = sum(s for _g, s in good_scrap.values())
        goal = goals.of(m.machine) if goals is not None else None
        whole = _Whole(report, goal, start, report.end, until, planned)
        machines.append(
            MachineFloor(
                m.machine,
                oee_of(m.totals, total_runs, standards, total_good, total_scrap, **whole.of()),
                [
                    oee_of(f, by_period[i], standards, *good_scrap.get(i, (0, 0)), **whole.of(p))
                    for i, (f, p) in enumerate(zip(m.periods, periods, strict=True))
                ],
                sorted(listed.get(m.machine, []), key=lambda s: s.stop.start),
                total_runs,
            )
        )
    index = {p.start: i for i, p in enumerate(periods)}
    return FloorReport(machines, pareto_of(lost), standards, covered, tuple(reasons), lost, index)


def _stops(
    session: Session,
    report: Report,
    names: list[str],
    found: dict[str, list[Stretch]],
) -> tuple[dict[str, list[StopWithReason]], tuple[date, date] | None]:
    """Every stop of the span that the summed days of lost time do not hold, with its
    reason and clipped at the span's end (summed ones and those found in the samples after
    the summed hours), and those days (None: no days, every stop is here)."""
    start, until = report.start, report.until or report.end
    days = None
    if until - start > LIST_ALL:
        days = covered_days(session, report.calendar, names, start, until)
    if days is None:
        summed = stops_with_reasons(session, names, start, until)
    else:
        cal = report.calendar
        lo, hi = cal.instant(days[0], time(0)), cal.instant(days[1], time(0))
        summed = stops_with_reasons(session, names, start, until, before=lo, after=hi)
    marks = marks_of(session, names)
    later: list[Stretch] = []
    owner: list[str] = []
    for name in names:
        mark = marks.get(name)
        for s in found.get(name, []):
            # a stop that ended by the mark is summed (and read above); later ones are not
            if s.end > start and s.start < until and (mark is None or s.end > mark.until):
                later.append(s)
                owner.append(name)
    picked = (
        reasons_for(session, sorted(set(owner)), min(s.start for s in later), until)
        if later
        else {}
    )
    out: dict[str, list[StopWithReason]] = {}
    for name in names:
        out[name] = [_clipped(s, until) for s in summed.get(name, [])]
    for name, s in zip(owner, later, strict=True):
        out[name] += with_reasons(name, [_clip(s, start, until)], picked)
    return out, days


def _clipped(s: StopWithReason, until: datetime) -> StopWithReason:
    if s.stop.end <= until:
        return s
    return StopWithReason(s.machine, _clip(s.stop, s.stop.start, until), s.reason, s.note, s.by)


def _longest(
    session: Session,
    report: Report,
    names: list[str],
    stops: dict[str, list[StopWithReason]],
) -> dict[str, list[StopWithReason]]:
    """Each machine's :data:`LISTED` longest stops of the span: the summed ones' as the
    report read them (:func:`.collect.longest_stops`, each with its reason; read here for a
    report that has none), with ``stops`` (those outside the summed days)."""
    start, until = report.start, report.until or report.end
    known = report.longest
    if known is None:
        known = longest_stops(session, names, start, until)
    out: dict[str, list[StopWithReason]] = {}
    for name in names:
        mine = {s.stop.start: s for s in stops.get(name, [])}
        for stop, reason, note, by in known.get(name, []):
            if stop.start not in mine:
                mine[stop.start] = _clipped(StopWithReason(name, stop, reason, note, by), until)
        out[name] = sorted(mine.values(), key=lambda s: (-s.seconds, s.stop.start))[:LISTED]
    return out


def pareto_of(lost: Lost) -> list[ParetoRow]:
    """The Pareto of every stop's lost time per reason (:func:`.downtime.pareto`'s order)."""
    rows: dict[str, ParetoRow] = {}
    for machine, by_reason in lost.totals.items():
        for name, (stops, seconds) in by_reason.items():
            if stops <= 0:
                continue
            row = rows.setdefault(name, ParetoRow(name))
            row.stops += int(stops)
            row.seconds += seconds
            row.machines.add(machine)
    return order_pareto(rows.values())


@dataclass(frozen=True)
class _Whole:
    """What a period's goal needs beyond its figures: its whole planned time, and the
    machine's configured goal over the whole period and up to now."""

    report: Report
    goal: Goal | None
    start: datetime
    end: datetime
    until: datetime
    # the planned time of each period, the same for every machine: worked out once per
    # report (the shifts of a year are a thousand instants on the shop's clock)
    planned: dict[tuple[datetime, datetime], float] = field(default_factory=dict)

    def of(self, period: Period | None = None) -> dict[str, Any]:
        """``oee_of``'s goal arguments for ``period`` (the whole span without one)."""
        a, b = (self.start, self.end) if period is None else (period.start, period.end)
        cal = self.report.calendar
        if self.goal is not None:
            now = min(b, self.until)
            return {"target": (self.goal.over(cal, a, b), self.goal.over(cal, a, now))}
        planned = self.planned.get((a, b))
        if planned is None:
            whole = sum(((y - x) for x, y in cal.scheduled(a, b)), timedelta())
            planned = self.planned[(a, b)] = whole.total_seconds()
        return {"planned_full": planned}


PerMachine = dict[str, tuple[list[dict[str, ProgramRuns]], list[Stretch]]]


def _runs_summed(
    session: Session,
    names: list[str],
    bins: list[Bin],
    periods: int,
    covered: datetime,
    until: datetime,
) -> PerMachine:
    """Each machine's runs per program and period over ``[covered, until)``, and the stops
    found after its summed hours: the whole hours from ``utilization_program_hours``, the
    hours not summed yet from the samples after the marks (with what the marks carry), and
    the rare hour a period boundary cuts (or a span's start within an hour) from the samples
    with :data:`LOOK_BACK` before it."""
    out: PerMachine = {n: ([{} for _ in range(periods)], []) for n in names}
    if not bins:
        return out
    marks = marks_of(session, names)
    summed_until = min((m.until for m in marks.values()), default=covered)
    slot_ids = {(b.period, b.in_shift): -1 if b.period is None else b.period for b in bins}
    raw, hour_slots = plan_hours(bins, slot_ids, covered, until, summed_until)
    hour_slots = [(h, slot) for h, slot in hour_slots if slot >= 0]
    for machine, slot, program, runs, seconds in program_sums(session, names, hour_slots):
        held = out[machine][0][slot].setdefault(program, ProgramRuns())
        held.runs += runs
        held.seconds += seconds
    tail_from = max(covered, min(summed_until, until))
    # (a cut hour just before the marks comes joined to the span after them: split it)
    spans = [
        piece
        for a, b in raw
        for piece in ([(a, tail_from), (tail_from, b)] if a < tail_from < b else [(a, b)])
    ]
    for a, b in spans:
        local = [
            Bin(max(x.start, a), min(x.end, b), x.period)
            for x in bins_within(bins, a, b)
            if x.period is not None
        ]
        if not local:
            continue
        is_tail = a >= tail_from
        read = read_many(session, names, a if is_tail else a - LOOK_BACK, b)
        for name in names:
            points = read[name]
            mark = marks.get(name)
            if is_tail and mark is not None and mark.until == a:
                sweep_from, carry = a, Carry.from_json(mark.carry)  # summed up to here
            elif is_tail:
                sweep_from, carry = a, Carry.fresh(in_force(points, a))
            else:  # followed from before the cut hour, counted within it
                first = points[0] if points else None
                sweep_from = min(a, first.at) if first is not None else a
                carry = Carry.fresh(first)
            found: list[Stretch] = []
            programs: list[dict[str, ProgramRuns]] = [{} for _ in local]
            sweep(points, sweep_from, b, local, carry, found, programs)
            _gather(out[name][0], local, programs)
            if is_tail:
                out[name][1].extend(found)
                if b == until:
                    out[name][1].extend(s for s in open_stretches(carry, until) if s.kind == "stop")
    return out


def _runs_of_every_sample(
    session: Session,
    names: list[str],
    bins: list[Bin],
    periods: int,
    covered: datetime,
    until: datetime,
) -> PerMachine:
    """The reference: each machine's runs per program and period from every one of its
    samples (what carries into ``covered`` known exactly), and all its stops."""
    out: PerMachine = {n: ([{} for _ in range(periods)], []) for n in names}
    if not bins:
        return out
    for name in names:
        points = read_points(session, name, datetime(1970, 1, 1, tzinfo=UTC), until)
        sweep_from = min(covered, points[0].at) if points else covered
        carry = Carry()
        found: list[Stretch] = []
        programs: list[dict[str, ProgramRuns]] = [{} for _ in bins]
        sweep(points, sweep_from, until, bins, carry, found, programs)
        _gather(out[name][0], bins, programs)
        out[name][1].extend(found)
        out[name][1].extend(s for s in open_stretches(carry, until) if s.kind == "stop")
    return out


def _gather(
    by_period: list[dict[str, ProgramRuns]],
    bins: Sequence[Bin],
    programs: list[dict[str, ProgramRuns]],
) -> None:
    """Add the runs of each bin to its period's."""
    for b, r in zip(bins, programs, strict=True):
        if b.period is not None:
            _merge(by_period[b.period], r)


def _merge(into: dict[str, ProgramRuns], more: dict[str, ProgramRuns]) -> None:
    for program, r in more.items():
        held = into.setdefault(program, ProgramRuns())
        held.runs += r.runs
        held.seconds += r.seconds


def _clip(s: Stretch, start: datetime, end: datetime) -> Stretch:
    """The stop as it counts in ``[start, end)`` (its start stays: it names the stop)."""
    if s.end <= end:
        return s
    return Stretch(s.kind, s.start, end, s.state, s.text, ongoing=True)


def _parts(
    session: Session,
    machines: Sequence[str],
    periods: Sequence[Period],
    start: datetime,
    end: datetime,
) -> dict[str, dict[int | None, tuple[int, int]]]:
    """Good and scrapped parts reported per machine and period (``None``: in no period)."""
    out: dict[str, dict[int | None, tuple[int, int]]] = defaultdict(dict)
    starts = [p.start for p in periods]
    # (the columns, not the rows as objects: a month of reports of 200 machines is 6 000)
    for machine, at, good_more, scrap_more in session.execute(
        select(PartReport.machine, PartReport.at, PartReport.good, PartReport.scrap).where(
            PartReport.machine.in_(machines), PartReport.at >= start, PartReport.at < end
        )
    ):
        at = as_utc(at)
        i = bisect.bisect_right(starts, at) - 1
        key = i if 0 <= i < len(periods) and periods[i].start <= at < periods[i].end else None
        good, scrap = out[machine].get(key, (0, 0))
        out[machine][key] = (good + good_more, scrap + scrap_more)
    return out
