"""Lost time per downtime reason summed per day and week (migration 0020) is the sum over
every stop: random timelines, reasons picked for some stops before the days are summed and
one after (which sums its day again), and a span of weeks whose stops are mostly read from
the summed rows. The reference follows every sample of the machine from its first with the
one state machine of utilization/sums.py and sums each stop by hand."""

from __future__ import annotations

from datetime import UTC, date, datetime, timedelta
from typing import Any

import pytest
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st
from sqlalchemy import select
from sqlalchemy.orm import Session, sessionmaker

from opendnc.server.config.downtime import DEFAULT_REASONS, NO_REASON
from opendnc.server.store.models import DowntimeReason, StatusSample, UtilizationStretch
from opendnc.server.utilization.collect import Group, read_points, report, sum_safely
from opendnc.server.utilization.lost import covered_days, repick
from opendnc.server.utilization.oee import LISTED, floor_of
from opendnc.server.utilization.sums import Bin, Carry, Stretch, as_utc, open_stretches, sweep
from tests.server.test_utilization_days import (
    CALENDARS,
    _names,
    _standards,
    _store,
    change,
    same_floor,
)

REASONS = DEFAULT_REASONS[:3]


def _every_stop(session: Session, machine: str, now: datetime) -> list[Stretch]:
    """Every stop of the machine up to ``now``, from all of its samples."""
    points = read_points(session, machine, datetime(2000, 1, 1, tzinfo=UTC), now)
    if not points:
        return []
    carry, found = Carry(), []
    sweep(points, points[0].at, now, [Bin(points[0].at, now)], carry, found)
    found += open_stretches(carry, now)
    return [s for s in found if s.kind == "stop"]


@settings(
    phases=[Phase.explicit, Phase.reuse, Phase.generate],
    max_examples=6,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(
    steps=st.lists(change, min_size=40, max_size=160),
    group=st.sampled_from(list(Group)),
    first_day=st.integers(0, 3),
    days=st.integers(6, 20),
    ongoing=st.booleans(),
)
def test_lost_time_per_reason_is_the_sum_over_every_stop(
    sessions: sessionmaker[Session],
    steps: list[Any],
    group: Group,
    first_day: int,
    days: int,
    ongoing: bool,
) -> None:
    cal = CALENDARS["berlin-3"]
    machines = [f"m{next(_names)}", f"n{next(_names)}"]
    monday = cal.instant(date(2026, 3, 2), datetime.min.time())
    for i, m in enumerate(machines):
        # (running at the end: no stop still going keeps the last days from being summed)
        timeline = [*steps[i:], (60, 0, False, False)]
        _store(sessions, m, monday - timedelta(hours=30 - 7 * i), timeline, counts=False)
    start = monday + timedelta(days=first_day, hours=5)
    # a span that ends in the past, or one that holds now (its last stop still going)
    end = start + timedelta(days=days, hours=3)
    now = end - timedelta(hours=20) if ongoing else end + timedelta(days=30)
    with sessions.begin() as session:
        sum_safely(session, machines, now)  # the hours: their stops are known
        stored = session.scalars(
            select(UtilizationStretch).where(
                UtilizationStretch.kind == "stop", UtilizationStretch.machine.in_(machines)
            )
        ).all()
        for k, s in enumerate(stored):
            if k % 2 == 0:
                session.add(
                    DowntimeReason(machine=s.machine, start=s.start, reason=REASONS[k % 3], by="t")
                )
        later = stored[1] if len(stored) > 1 else None
    with sessions.begin() as session:
        sum_safely(session, machines, now, cal)  # the days, their stops' lost time with them
    if later is not None:  # a reason picked for a stop of a summed day
        with sessions.begin() as session:
            session.add(
                DowntimeReason(machine=later.machine, start=later.start, reason="other", by="t")
            )
            session.flush()
            repick(session, cal, later.machine, as_utc(later.start))
    _standards(sessions)
    with sessions.begin() as session:
        r = report(session, cal, machines, start, end, group, now=now)
        until = r.until or r.end
        floor = floor_of(session, r, timedelta(days=400), (*REASONS, "other"), now)
        # (with ``ongoing``, the runs after the summed hours come from the samples)
        same_floor(session, r, now, timedelta(days=400))
        if not ongoing:  # the summed days are read (not every stop one by one)
            assert covered_days(session, cal, machines, start, until) is not None
        picked = {
            (x.machine, as_utc(x.start)): x.reason
            for x in session.scalars(
                select(DowntimeReason).where(DowntimeReason.machine.in_(machines))
            )
        }
        every = {m: _every_stop(session, m, now) for m in machines}
    pareto: dict[str, list[float]] = {}
    for m in machines:
        total: dict[str, float] = {}
        per_period: list[dict[str, float]] = [{} for _ in r.periods]
        mine = [s for s in every[m] if s.end > start and s.start < until]
        for s in mine:
            reason = picked.get((m, s.start), NO_REASON)
            seconds = (min(s.end, until) - s.start).total_seconds()
            total[reason] = total.get(reason, 0.0) + seconds
            row = pareto.setdefault(reason, [0, 0.0])
            row[0] += 1
            row[1] += seconds
            for i, p in enumerate(r.periods):
                if p.start <= s.start < p.end:
                    per_period[i][reason] = per_period[i].get(reason, 0.0) + seconds
        got = {k: v for k, v in floor.lost_by_reason(m).items() if v}
        assert got == pytest.approx(total, abs=1e-3)
        for i, p in enumerate(r.periods):
            got = {k: v for k, v in floor.lost_by_reason(m, p).items() if v}
            assert got == pytest.approx(per_period[i], abs=1e-3), p.key
        # the listed stops: the longest of them, whole and with their reasons
        listed = floor.of(m)
        assert listed is not None
        longest = sorted(mine, key=lambda s: (-(min(s.end, until) - s.start), s.start))[:LISTED]
        assert sorted(s.stop.start for s in listed.stops) == sorted(s.start for s in longest)
        for s in listed.stops:
            assert s.reason == picked.get((m, s.stop.start), "")
    got_pareto = {p.reason: [p.stops, p.seconds] for p in floor.pareto}
    assert set(got_pareto) == set(pareto)
    for reason, (count, seconds) in pareto.items():
        assert got_pareto[reason][0] == count
        assert got_pareto[reason][1] == pytest.approx(seconds, abs=1e-3)


def _samples(sessions: sessionmaker[Session], machine: str, changes: list[Any]) -> None:
    """``machine``'s samples: (at, state, execution, alarm) each."""
    with sessions.begin() as session:
        session.add_all(
            StatusSample(machine=machine, at=at, state=state, execution=execution, alarm=alarm)
            for at, state, execution, alarm in changes
        )


def _cycles(first: datetime, last: datetime) -> list[Any]:
    """Running 40 minutes and ready 10 (a stop each time) from ``first`` to ``last``."""
    out, at = [], first
    while at < last:
        out.append((at, "running", "ACTIVE", ""))
        out.append((at + timedelta(minutes=40), "ready", "READY", ""))
        at += timedelta(minutes=50)
    return out


def test_stops_longer_than_the_cut_days_count_whole(sessions: sessionmaker[Session]) -> None:
    """A long span reads the stops outside its summed days from two ranges of the start's
    index, bounded by the longest stop: a machine offline for three days into the span's
    first day counts from where it began, and an alarm of a summed day that outlasts the
    span counts up to the span's end."""
    cal = CALENDARS["berlin-3"]
    machine = f"m{next(_names)}"
    monday = cal.instant(date(2026, 3, 2), datetime.min.time())
    start = monday + timedelta(days=7, hours=10, minutes=20)  # a Monday morning
    offline = start - timedelta(days=3) + timedelta(hours=5)  # to 5 hours into the span
    alarm = start + timedelta(days=12, minutes=7)  # 8 days long, 4 of them in the span
    end = alarm + timedelta(days=4)
    now = alarm + timedelta(days=10)
    _samples(
        sessions,
        machine,
        [
            *_cycles(monday - timedelta(days=1), offline),
            (offline, "offline", "", ""),
            *_cycles(offline + timedelta(days=3), alarm),
            (alarm, "alarm", "STOPPED", "1010 SPINDLE"),
            *_cycles(alarm + timedelta(days=8), now),
        ],
    )
    with sessions.begin() as session:
        sum_safely(session, [machine], now, cal)
    with sessions.begin() as session:
        stops = _every_stop(session, machine, now)
        r = report(session, cal, [machine], start, end, Group.DAY, now=now)
        assert r.until == end
        assert covered_days(session, cal, [machine], start, end) is not None
        floor = floor_of(session, r, timedelta(days=400), REASONS, now)
    mine = [s for s in stops if s.end > start and s.start < end]
    assert {(s.start, s.seconds) for s in mine} >= {(offline, 3 * 86400), (alarm, 8 * 86400)}
    got = floor.lost_by_reason(machine)
    expected = sum((min(s.end, end) - s.start).total_seconds() for s in mine)
    assert got == {**dict.fromkeys(REASONS, 0.0), NO_REASON: pytest.approx(expected, abs=1e-3)}
    for p in r.periods:
        began = [s for s in mine if p.start <= s.start < p.end]
        lost = sum((min(s.end, end) - s.start).total_seconds() for s in began)
        assert floor.lost_by_reason(machine, p)[NO_REASON] == pytest.approx(lost, abs=1e-3)
    listed = floor.of(machine)
    assert listed is not None
    assert {offline, alarm} <= {s.stop.start for s in listed.stops}


@pytest.mark.parametrize("cycles", [15, 60])
def test_the_longest_stops_of_equal_length_are_the_earliest(
    sessions: sessionmaker[Session], cycles: int
) -> None:
    """Stops as long as one another are listed earliest first, in the report (its 10) and
    in OEE's list (20), also where the limit of the query cuts through them."""
    cal = CALENDARS["berlin-3"]
    machine = f"m{next(_names)}"
    start = cal.instant(date(2026, 3, 9), datetime.min.time()) + timedelta(hours=6)
    first = start + timedelta(days=2)  # every stop 10 minutes, all within days 3 and 4
    end = start + timedelta(days=6)
    last = first + timedelta(minutes=50 * cycles)
    _samples(sessions, machine, [*_cycles(first, last), (last, "running", "ACTIVE", "")])
    with sessions.begin() as session:
        sum_safely(session, [machine], end + timedelta(days=1), cal)
    with sessions.begin() as session:
        stops = _every_stop(session, machine, end)
        r = report(session, cal, [machine], start, end, Group.DAY, now=end + timedelta(days=1))
        floor = floor_of(session, r, timedelta(days=400), REASONS, end + timedelta(days=1))
    assert len(stops) == cycles
    assert {s.seconds for s in stops} == {600.0}
    starts = sorted(s.start for s in stops)
    assert [s.start for s in r.machines[0].stops] == starts[:10]
    listed = floor.of(machine)
    assert listed is not None
    assert sorted(s.stop.start for s in listed.stops) == starts[:LISTED]
