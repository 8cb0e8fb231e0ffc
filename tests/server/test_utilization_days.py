"""The summed local days answer what reading every sample answers, on SQLite and PostgreSQL:
random timelines (hypothesis) across both clock changes, with overnight shifts, a shift
ending at 24:00, a shop without shifts, another zone, and a calendar the days cannot be
summed for (a shift at 05:30: its questions read the hours); a late sample and a changed
calendar sum the days again. OEE's runs per program (summed with the hours, migration 0023)
are what following every sample counts, and migration 0023 sums the kept hours again."""

from __future__ import annotations

import itertools
from dataclasses import astuple
from datetime import UTC, date, datetime, timedelta
from typing import Any

import pytest
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st
from sqlalchemy import func, select
from sqlalchemy.orm import Session, sessionmaker

from opendnc.server.core.shifts import Calendar, parse_calendar
from opendnc.server.store.db import (
    current_revision,
    head_revision,
    make_engine,
    make_sessions,
    migrate,
)
from opendnc.server.store.models import (
    Blob,
    Program,
    ProgramState,
    ProgramVersion,
    StandardTime,
    StatusSample,
    UtilizationDay,
    UtilizationMark,
    UtilizationProgramHour,
    VersionCheck,
)
from opendnc.server.utilization.collect import Group, MachineReport, Report, report, sum_safely
from opendnc.server.utilization.days import day_span, pieces_of, rolls_up
from opendnc.server.utilization.oee import FloorReport, Oee, floor_of
from tests.server.test_utilization_db import _whole


def _calendar(zone: str, shifts: list[dict[str, Any]]) -> Calendar:
    return parse_calendar({"server": {"timezone": zone}, "shifts": shifts})


THREE = [
    {"name": "early", "start": "06:00", "end": "14:00", "days": ["mon-fri"]},
    {"name": "late", "start": "14:00", "end": "22:00", "days": ["mon-fri"]},
    {"name": "night", "start": "22:00", "end": "06:00", "days": ["sun-thu"]},
]
CALENDARS = {
    "berlin-3": _calendar("Europe/Berlin", THREE),
    "berlin-none": _calendar("Europe/Berlin", []),
    "berlin-to-midnight": _calendar(
        "Europe/Berlin",
        [
            {"name": "day", "start": "07:00", "end": "16:00", "days": ["mon-sat"]},
            {"name": "evening", "start": "16:00", "end": "24:00", "days": ["mon-fri"]},
        ],
    ),
    "chicago-night": _calendar(
        "America/Chicago",
        [{"name": "night", "start": "20:00", "end": "04:00", "days": ["sat", "sun", "mon"]}],
    ),
    "berlin-half-hour": _calendar(
        "Europe/Berlin", [{"name": "early", "start": "05:30", "end": "13:30", "days": ["mon-fri"]}]
    ),
}
# both clock changes: Europe on 2026-03-29 and 2026-10-25, the US on 2026-03-08 and 11-01
WEEKS = [date(2026, 3, 23), date(2026, 3, 2), date(2026, 10, 19), date(2026, 10, 26)]
STATES = [
    ("running", "ACTIVE", ""),
    ("ready", "READY", ""),
    ("ready", "", ""),
    ("stopped", "FEED_HOLD", ""),
    ("alarm", "STOPPED", "1010 SPINDLE"),
    ("alarm", "STOPPED", "EMERGENCY STOP"),
    ("offline", "", ""),
    ("none", "", ""),
]
# programs as controls name them: one with the TNC's folder (the library's "o2.h")
PROGRAMS = ["O1", "TNC:\\nc_prog\\O2.H", "o2.h", ""]
_names = itertools.count(1)

# one change: seconds to the next one, the state, whether a part was made
change = st.tuples(
    st.integers(30, 5 * 3600), st.sampled_from(range(len(STATES))), st.booleans(), st.booleans()
)


def _store(
    sessions: sessionmaker[Session], machine: str, start: datetime, steps: list[Any], counts: bool
) -> None:
    rows, at, count = [], start, 100
    for gap, index, part, reset in steps:
        state, execution, alarm = STATES[index]
        if counts and part:
            count = 0 if reset else count + 1
        rows.append(
            StatusSample(
                machine=machine,
                at=at,
                state=state,
                execution=execution,
                program=PROGRAMS[gap % len(PROGRAMS)],
                part_count=count if counts else None,
                alarm=alarm,
            )
        )
        at += timedelta(seconds=gap)
    with sessions.begin() as session:
        session.add_all(rows)


def _same(a: list[MachineReport], b: list[MachineReport]) -> None:
    for x, y in zip(a, b, strict=True):
        assert _whole(x) == _whole(y)


def _standards(sessions: sessionmaker[Session]) -> None:
    """A standard time for "o1" (set) and "o2.h" (the check's estimate); none for the
    unnamed program."""
    with sessions.begin() as session:
        if session.scalar(select(func.count()).select_from(Program)):
            return  # (hypothesis runs the test again on the same database)
        session.add(Blob(sha256="0" * 64, size=1, data=b"%"))
        for name, seconds in (("O1", 600.0), ("O2.H", 90.0)):
            program = Program(name=name)
            session.add(program)
            session.flush()
            version = ProgramVersion(
                program_id=program.id,
                number=1,
                sha256="0" * 64,
                size=1,
                state=ProgramState.RELEASED,
                author="t",
            )
            session.add(version)
            session.flush()
            if name == "O1":
                session.add(StandardTime(version_id=version.id, seconds=seconds, set_by="t"))
            else:
                facts = {"cycle_time_s": seconds}
                session.add(
                    VersionCheck(version_id=version.id, limits="", control="tnc", facts=facts)
                )


def _oee(o: Oee) -> tuple[object, ...]:
    return tuple(round(v, 6) if isinstance(v, float) else v for v in astuple(o))


def same_floor(session: Session, r: Report, now: datetime, retention: timedelta) -> FloorReport:
    """OEE read from the summed runs per program is what following every sample gives
    (per machine, in total and per period, and the runs per program); the summed one."""
    summed = floor_of(session, r, retention, (), now)
    read = floor_of(session, r, retention, (), now, use_sums=False)
    assert summed.covered_from == read.covered_from
    for x, y in zip(summed.machines, read.machines, strict=True):
        runs = {k: (v.runs, round(v.seconds, 3)) for k, v in x.runs.items() if v.runs or v.seconds}
        assert runs == {
            k: (v.runs, round(v.seconds, 3)) for k, v in y.runs.items() if v.runs or v.seconds
        }
        assert _oee(x.totals) == _oee(y.totals)
        assert [_oee(o) for o in x.periods] == [_oee(o) for o in y.periods]
    return summed


@settings(
    phases=[Phase.explicit, Phase.reuse, Phase.generate],
    max_examples=12,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(
    calendar=st.sampled_from(sorted(CALENDARS)),
    week=st.sampled_from(WEEKS),
    lead=st.integers(0, 6 * 3600),
    steps=st.lists(change, min_size=1, max_size=120),
    counts=st.booleans(),
    cut=st.tuples(st.integers(0, 2), st.integers(0, 23), st.integers(3, 9), st.integers(0, 23)),
    group=st.sampled_from(list(Group)),
)
def test_summed_days_answer_what_every_sample_answers(
    sessions: sessionmaker[Session],
    calendar: str,
    week: date,
    lead: int,
    steps: list[Any],
    counts: bool,
    cut: tuple[int, int, int, int],
    group: Group,
) -> None:
    cal = CALENDARS[calendar]
    machines = [f"m{next(_names)}", f"never{next(_names)}"]
    monday = cal.instant(week, datetime.min.time())
    _store(
        sessions, machines[0], monday - timedelta(days=1) + timedelta(seconds=lead), steps, counts
    )
    # a span of whole local hours: its first and last days cut, whole days between
    first_day, first_hour, days, last_hour = cut
    start = cal.local(monday + timedelta(days=first_day)).replace(hour=first_hour)
    end = (start + timedelta(days=days)).replace(hour=last_hour)
    start, end = start.astimezone(UTC), end.astimezone(UTC)
    now = monday + timedelta(days=14)
    with sessions.begin() as session:
        summed = report(session, cal, machines, start, end, group, now=now)
    with sessions.begin() as session:
        read = report(session, cal, machines, start, end, group, now=now, use_hours=False)
        hours = report(session, cal, machines, start, end, group, now=now, use_days=False)
    assert [p.key for p in summed.periods] == [p.key for p in read.periods]
    _same(summed.machines, read.machines)
    _same(hours.machines, read.machines)
    # OEE's runs per program from the summed hours: over the whole span, and from a
    # retention that ends within it (the runs are counted from its first whole hour)
    _standards(sessions)
    with sessions.begin() as session:
        whole = same_floor(session, summed, now, timedelta(days=400))
        assert whole.covered_from == start
        within = now - (start + (end - start) / 3 + timedelta(minutes=17))
        same_floor(session, summed, now, within)
    with sessions() as session:  # and the days were what answered (where they can)
        marks = {m.machine: m for m in session.scalars(select(UtilizationMark))}
        mine = {k: v for k, v in marks.items() if k in machines}
        used = day_span(session, cal, machines, mine, start, end)
    assert (used is not None) == (rolls_up(cal) and days >= 3)


def test_days_are_pieces_of_the_calendar_on_the_hour() -> None:
    cal = CALENDARS["berlin-3"]
    spring = pieces_of(cal, date(2026, 3, 29))  # a Sunday of 23 hours, a night shift at 22:00
    assert [(p.shift, p.shift_day.isoformat()) for p in spring] == [
        ("", "2026-03-29"),
        ("night", "2026-03-29"),
    ]
    assert sum((p.end - p.start).total_seconds() for p in spring) == 23 * 3600
    monday = pieces_of(cal, date(2026, 3, 30))
    assert [(p.shift, p.shift_day.day) for p in monday] == [
        ("night", 29),
        ("early", 30),
        ("late", 30),
        ("night", 30),
    ]
    assert rolls_up(cal)
    assert not rolls_up(CALENDARS["berlin-half-hour"])
    assert not rolls_up(_calendar("Asia/Kolkata", []))
    overlapping = [
        {"name": "a", "start": "06:00", "end": "15:00", "days": ["mon"]},
        {"name": "b", "start": "14:00", "end": "22:00", "days": ["mon"]},
    ]
    assert not rolls_up(_calendar("Europe/Berlin", overlapping))


def _timeline(sessions: sessionmaker[Session], machine: str, start: datetime) -> None:
    steps = [(1800 + 97 * i % 3000, i % len(STATES), i % 3 == 0, i % 41 == 0) for i in range(400)]
    _store(sessions, machine, start, steps, counts=True)


def test_a_late_sample_sums_the_days_again(sessions: sessionmaker[Session]) -> None:
    cal = CALENDARS["berlin-3"]
    start = cal.instant(date(2026, 3, 23), datetime.min.time())
    end, now = start + timedelta(days=7), start + timedelta(days=9)
    _timeline(sessions, "m", start - timedelta(hours=3))
    with sessions.begin() as session:
        report(session, cal, ["m"], start, end, Group.DAY, now=now)
    with sessions() as session:
        assert session.scalar(select(func.count()).select_from(UtilizationDay)) > 0
    with sessions.begin() as session:  # the recorder's queue reaches the database late
        session.add(
            StatusSample(
                machine="m", at=start + timedelta(days=3, hours=2), state="alarm", alarm="LATE"
            )
        )
    with sessions.begin() as session:
        summed = report(session, cal, ["m"], start, end, Group.DAY, now=now)
    with sessions.begin() as session:
        read = report(session, cal, ["m"], start, end, Group.DAY, now=now, use_hours=False)
    # (not the stops: a stop open where the hours are summed again restarts there, as the
    # hours summed again always did)
    a, b = _whole(summed.machines[0]), _whole(read.machines[0])
    assert (a[:3], a[4:]) == (b[:3], b[4:])
    assert "LATE" in {a.text for a in summed.machines[0].alarms}


def test_another_calendar_sums_the_days_again(sessions: sessionmaker[Session]) -> None:
    first, second = CALENDARS["berlin-3"], CALENDARS["berlin-to-midnight"]
    start = first.instant(date(2026, 10, 19), datetime.min.time())
    end, now = start + timedelta(days=10), start + timedelta(days=12)
    _timeline(sessions, "m", start)
    for cal in (first, second, first):
        with sessions.begin() as session:
            sum_safely(session, ["m"], now, cal)
        with sessions.begin() as session:
            summed = report(session, cal, ["m"], start, end, Group.SHIFT, now=now)
        with sessions.begin() as session:
            read = report(session, cal, ["m"], start, end, Group.SHIFT, now=now, use_hours=False)
        _same(summed.machines, read.machines)
        with sessions() as session:
            marks = {m.machine: m for m in session.scalars(select(UtilizationMark))}
            assert day_span(session, cal, ["m"], marks, start, end) is not None


@pytest.mark.parametrize("group", list(Group))
def test_a_machine_without_samples_has_no_record_on_summed_days(
    sessions: sessionmaker[Session], group: Group
) -> None:
    cal = CALENDARS["berlin-3"]
    start = cal.instant(date(2026, 3, 23), datetime.min.time())
    end, now = start + timedelta(days=8), start + timedelta(days=9)
    _timeline(sessions, "m", start)
    with sessions.begin() as session:
        r = report(session, cal, ["m", "new"], start, end, group, now=now)
    new = r.machines[1]
    assert new.totals.seconds == {
        s: ((end - start).total_seconds() if s.value == "no_record" else 0.0)
        for s in new.totals.seconds
    }
    assert new.totals.scheduled_total == sum(
        (b - a).total_seconds() for a, b in cal.scheduled(start, end)
    )


def test_migration_0023_sums_the_kept_hours_again_with_their_programs(db_url: str) -> None:
    engine = make_engine(db_url)
    try:
        migrate(engine)
        sessions = make_sessions(engine)
        cal = CALENDARS["berlin-3"]
        start = cal.instant(date(2026, 3, 23), datetime.min.time())
        end, now = start + timedelta(days=6), start + timedelta(days=7)
        _timeline(sessions, "m", start)
        _standards(sessions)
        with sessions.begin() as session:
            sum_safely(session, ["m"], now, cal)
        # a server before 0023 summed these hours: none of their runs per program is kept
        migrate(engine, "0022")
        migrate(engine)
        assert current_revision(engine) == head_revision()
        with sessions() as session:
            assert session.scalar(select(func.count()).select_from(UtilizationProgramHour)) == 0
            assert session.scalar(select(UtilizationMark.last_id)) == 0
        with sessions.begin() as session:  # the next summing sums the kept hours again
            r = report(session, cal, ["m"], start, end, Group.DAY, now=now)
            floor = same_floor(session, r, now, timedelta(days=400))
        programs = floor.machines[0].runs
        assert "o1" in programs
        assert sum(p.runs for p in programs.values()) == r.machines[0].totals.runs > 0
        with sessions() as session:
            assert session.scalar(select(func.count()).select_from(UtilizationProgramHour)) > 0
    finally:
        engine.dispose()
