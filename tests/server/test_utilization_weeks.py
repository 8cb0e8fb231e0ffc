"""The summed weeks (migration 0016) answer what the test's own arithmetic answers, on SQLite
and PostgreSQL: a machine repeats the same day for five weeks across the spring clock change,
so the seconds in each state per week, within shifts and in all, the parts, runs and alarms
are known from the timeline the test writes; the days are summed a few at a time, so weeks
are closed across those rounds; a late sample and another calendar sum the weeks again."""

from __future__ import annotations

from datetime import UTC, date, datetime, time, timedelta
from zoneinfo import ZoneInfo

from sqlalchemy import select
from sqlalchemy.orm import Session, sessionmaker

from opendnc.server.core.shifts import Calendar, parse_calendar
from opendnc.server.core.state import State
from opendnc.server.store.models import StatusSample, UtilizationWeek
from opendnc.server.utilization.collect import Group, marks_of, report, sum_safely
from opendnc.server.utilization.days import build_days
from tests.server.test_utilization_db import _figures, _whole

BERLIN = ZoneInfo("Europe/Berlin")
THREE = parse_calendar(
    {
        "server": {"timezone": "Europe/Berlin"},
        "shifts": [
            {"name": "early", "start": "06:00", "end": "14:00", "days": ["mon-fri"]},
            {"name": "late", "start": "14:00", "end": "22:00", "days": ["mon-fri"]},
            {"name": "night", "start": "22:00", "end": "06:00", "days": ["sun-thu"]},
        ],
    }
)
NO_SHIFTS = parse_calendar({"server": {"timezone": "Europe/Berlin"}, "shifts": []})
# the shifts above as local hours per weekday (Monday 0): a night shift's morning part
# belongs to the day it ends on
IN_SHIFT = {
    0: [(0, 24)],
    1: [(0, 24)],
    2: [(0, 24)],
    3: [(0, 24)],
    4: [(0, 22)],
    5: [],
    6: [(22, 24)],
}
# one day of the machine: from (hour, minute) local on, the state (execution word, alarm);
# the part counter goes up at 10:00 and 22:00, each ending a run
DAY = [
    ((0, 0), "ready", "READY", ""),
    ((6, 0), "running", "ACTIVE", ""),
    ((10, 0), "ready", "READY", ""),
    ((12, 0), "alarm", "STOPPED", "1010 SPINDLE OVERLOAD"),
    ((12, 30), "stopped", "FEED_HOLD", ""),
    ((13, 0), "running", "ACTIVE", ""),
    ((22, 0), "ready", "READY", ""),
    ((23, 0), "offline", "", ""),
]
COUNTS_AT = {(10, 0), (22, 0)}
FIRST = date(2026, 3, 18)  # a Wednesday; the clocks go forward on Sunday 29 March
DAYS = 37  # up to Thursday 23 April
SPAN = (date(2026, 3, 19), date(2026, 4, 23))  # Thursday to Thursday: 4 whole weeks between
NOW = datetime(2026, 4, 26, 12, tzinfo=UTC)
Interval = tuple[datetime, datetime]


def _local(day: date, hour: int, minute: int = 0) -> datetime:
    return datetime.combine(day, time(hour, minute), BERLIN).astimezone(UTC)


def _write(sessions: sessionmaker[Session], machine: str) -> dict[State, list[Interval]]:
    """Store the machine's days; what it did when, by state, as the test knows it."""
    rows: list[StatusSample] = []
    spans: dict[State, list[Interval]] = {s: [] for s in State}
    count = 100
    for n in range(DAYS):
        day = FIRST + timedelta(days=n)
        for i, ((hour, minute), state, execution, alarm) in enumerate(DAY):
            at = _local(day, hour, minute)
            if (hour, minute) in COUNTS_AT:
                count += 1
            rows.append(
                StatusSample(
                    machine=machine,
                    at=at,
                    state=state,
                    execution=execution,
                    program="O1",
                    part_count=count,
                    alarm=alarm,
                )
            )
            if i + 1 < len(DAY):
                until = _local(day, *DAY[i + 1][0])
            else:
                until = _local(day + timedelta(days=1), 0)
            spans[State(state)].append((at, until))
    with sessions.begin() as session:
        session.add_all(rows)
    return spans


def _shift_time(a: date, b: date) -> list[Interval]:
    out = []
    day = a
    while day < b:
        for start, end in IN_SHIFT[day.weekday()]:
            out.append(
                (
                    _local(day, start),
                    _local(day + timedelta(days=1), 0) if end == 24 else _local(day, end),
                )
            )
        day += timedelta(days=1)
    return out


def _overlap(xs: list[Interval], ys: list[Interval]) -> float:
    return sum(max(0.0, (min(b, d) - max(a, c)).total_seconds()) for a, b in xs for c, d in ys)


def _weeks(a: date, b: date) -> list[tuple[date, date]]:
    """The calendar weeks of the days ``[a, b)``, cut to them."""
    out = []
    monday = a - timedelta(days=a.weekday())
    while monday < b:
        out.append((max(a, monday), min(b, monday + timedelta(days=7))))
        monday += timedelta(days=7)
    return out


def _summed_weeks(sessions: sessionmaker[Session], machine: str) -> dict[date, float]:
    with sessions() as session:
        rows = session.scalars(select(UtilizationWeek).where(UtilizationWeek.machine == machine))
        return {w.week: w.running for w in rows}


def _sum_in_rounds(sessions: sessionmaker[Session], calendar: Calendar, machine: str) -> None:
    """The hours, then the days three at a time: weeks close across the rounds."""
    with sessions.begin() as session:
        sum_safely(session, [machine], NOW, calendar, days=3)
    while True:
        with sessions.begin() as session:
            if not build_days(session, calendar, [machine], marks_of(session), limit=3):
                return


def test_a_year_by_week_is_the_weeks_of_the_timeline(sessions: sessionmaker[Session]) -> None:
    spans = _write(sessions, "m")
    _sum_in_rounds(sessions, THREE, "m")
    # every week whose days were all summed, from the first sample's on (its days before
    # that are no record); the week still open is not
    assert _summed_weeks(sessions, "m").keys() == {
        date(2026, 3, 16),
        date(2026, 3, 23),
        date(2026, 3, 30),
        date(2026, 4, 6),
        date(2026, 4, 13),
    }
    start, end = _local(SPAN[0], 0), _local(SPAN[1], 0)
    with sessions.begin() as session:
        r = report(session, THREE, ["m"], start, end, Group.WEEK, now=NOW)
    weeks = _weeks(*SPAN)
    assert [p.key for p in r.periods] == [
        f"{a.isocalendar()[0]}-W{a.isocalendar()[1]:02d}" for a, _b in weeks
    ]
    m = r.machines[0]
    for (a, b), f in zip(weeks, m.periods, strict=True):
        period = [(_local(a, 0), _local(b, 0))]
        shifts = _shift_time(a, b)
        days = (b - a).days
        for state, held in spans.items():
            assert f.seconds[state] == _overlap(held, period), (a, state)
            in_shift = [(max(x, y), min(x2, y2)) for x, x2 in held for y, y2 in shifts]
            assert f.scheduled[state] == _overlap(in_shift, period), (a, state)
        assert f.parts == 2 * days
        assert f.runs == f.cycles == 2 * days
        assert f.cycle_seconds == 13 * 3600 * days
    # the week of the clock change has 167 hours, its Sunday night one hour less of ready
    spring = m.periods[1]
    assert spring.total == 167 * 3600
    assert spring.seconds[State.READY] == (7 * 9 - 1) * 3600
    assert spring.seconds[State.RUNNING] == 7 * 13 * 3600
    days = (SPAN[1] - SPAN[0]).days
    assert [(a.text, a.count, a.seconds, a.longest) for a in m.alarms] == [
        ("1010 SPINDLE OVERLOAD", days, days * 1800.0, 1800.0)
    ]
    # and all of it as every sample and the summed hours answer it
    with sessions.begin() as session:
        read = report(session, THREE, ["m"], start, end, Group.WEEK, now=NOW, use_hours=False)
        hours = report(session, THREE, ["m"], start, end, Group.WEEK, now=NOW, use_days=False)
    assert _whole(m) == _whole(read.machines[0]) == _whole(hours.machines[0])


def test_a_late_sample_and_another_calendar_sum_the_weeks_again(
    sessions: sessionmaker[Session],
) -> None:
    _write(sessions, "m")
    _sum_in_rounds(sessions, THREE, "m")
    before = _summed_weeks(sessions, "m")
    # the recorder's queue reaches the database late: an alarm on Wednesday 1 April from
    # 15:00 to the evening's ready at 22:00 instead of running
    with sessions.begin() as session:
        session.add(
            StatusSample(machine="m", at=_local(date(2026, 4, 1), 15), state="alarm", alarm="LATE")
        )
    start, end = _local(SPAN[0], 0), _local(SPAN[1], 0)
    for calendar in (THREE, NO_SHIFTS):
        with sessions.begin() as session:
            summed = report(session, calendar, ["m"], start, end, Group.WEEK, now=NOW)
        with sessions.begin() as session:
            read = report(
                session, calendar, ["m"], start, end, Group.WEEK, now=NOW, use_hours=False
            )
        # (not the stops and cycles: a stop or a run open where the hours are summed again
        # restarts there, its start unknown to them)
        x, y = summed.machines[0], read.machines[0]
        for f, g in zip([x.totals, *x.periods], [y.totals, *y.periods], strict=True):
            assert _figures(f)[:4] == _figures(g)[:4]
        assert _whole(x)[4:] == _whole(y)[4:]
        after = _summed_weeks(sessions, "m")
        assert after.keys() == before.keys()
        late = date(2026, 3, 30)
        assert after[late] == before[late] - 7 * 3600
        assert {w: v for w, v in after.items() if w != late} == {
            w: v for w, v in before.items() if w != late
        }
    # without shifts every hour is shift time
    assert all(
        f.scheduled == f.seconds for f in [summed.machines[0].totals, *summed.machines[0].periods]
    )
