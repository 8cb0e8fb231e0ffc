"""Utilization in the database, on SQLite and PostgreSQL: the summed hours answer what reading
every sample answers (random timelines across the spring clock change), a sample that arrives
late for a summed hour is summed again, the recorder stores what utilization needs, the server
sums in the background, and migration 0007 goes up from 0004 (through those between) and back."""

from __future__ import annotations

import asyncio
import json
import random
import time
from datetime import UTC, datetime, timedelta
from pathlib import Path
from zoneinfo import ZoneInfo

import pytest
from sqlalchemy import Engine, func, inspect, select, text
from sqlalchemy.orm import Session, sessionmaker

from opendnc.server.config.shop import parse_config
from opendnc.server.core.shifts import parse_calendar
from opendnc.server.core.state import State
from opendnc.server.core.status import MachineStatus
from opendnc.server.machines.timeline import Timeline
from opendnc.server.store.db import current_revision, make_engine, migrate, read_only
from opendnc.server.store.models import StatusSample, UtilizationHour, UtilizationMark
from opendnc.server.utilization import answer, component
from opendnc.server.utilization.collect import Figures, Group, MachineReport, report, sum_safely

BERLIN = ZoneInfo("Europe/Berlin")
CAL = parse_calendar(
    {
        "server": {"timezone": "Europe/Berlin"},
        "shifts": [
            {"name": "early", "start": "06:00", "end": "14:00", "days": ["mon-fri"]},
            {"name": "late", "start": "14:00", "end": "22:00", "days": ["mon-fri"]},
            {"name": "night", "start": "22:00", "end": "06:00", "days": ["sun-thu"]},
        ],
    }
)
START = datetime(2026, 3, 23, tzinfo=BERLIN)  # Monday; the clocks change on Sunday 29th
END = datetime(2026, 4, 2, tzinfo=BERLIN)
NOW = END + timedelta(days=1)
MACHINES = ["tnc-1", "haas-1", "quiet-1", "never-1"]


def _random_timeline(sessions: sessionmaker[Session], seed: int) -> None:
    rng = random.Random(seed)
    rows = []
    for machine in MACHINES[:3]:
        at = START - timedelta(hours=5) + timedelta(minutes=rng.randint(0, 59))
        count = 40
        while at < END + timedelta(hours=3):
            state, execution, alarm = rng.choice(
                [
                    ("running", "ACTIVE", ""),
                    ("active", "ACTIVE", ""),  # the old word for it
                    ("ready", "READY", ""),
                    ("ready", "", ""),  # a control that said nothing
                    ("stopped", "FEED_HOLD", ""),
                    ("alarm", "STOPPED", rng.choice(["1010 SPINDLE", "ALARM"])),
                    ("offline", "", ""),
                    ("none", "", ""),
                ]
            )
            part_count = None
            if machine == "haas-1":
                if state == "ready" and rng.random() < 0.7:
                    count += 1
                if rng.random() < 0.02:
                    count = 0  # the operator reset the counter
                part_count = count
            rows.append(
                StatusSample(
                    machine=machine,
                    at=at,
                    state=state,
                    mode="",
                    execution=execution,
                    program="O1",
                    part_count=part_count,
                    alarm=alarm,
                )
            )
            # quiet-1 changes every few hours, the others every few minutes
            gap = rng.randint(60, 4 * 3600) if machine == "quiet-1" else rng.randint(20, 2400)
            at += timedelta(seconds=gap)
    with sessions.begin() as session:
        session.add_all(rows)


def _figures(f: Figures) -> tuple[object, ...]:
    return (
        tuple(round(f.seconds[s], 3) for s in State),
        tuple(round(f.scheduled[s], 3) for s in State),
        f.parts,
        f.runs,
        f.cycles,
        round(f.cycle_seconds, 3),
    )


def _whole(m: MachineReport) -> tuple[object, ...]:
    return (
        m.machine,
        _figures(m.totals),
        [_figures(f) for f in m.periods],
        [(s.start, s.end, s.state, s.text, s.ongoing) for s in m.stops],
        [(a.text, a.count, round(a.seconds, 3), round(a.longest, 3)) for a in m.alarms],
        [(a.start, a.end, a.text) for a in m.recent_alarms],
    )


@pytest.mark.parametrize("seed", [1, 2])
def test_summed_hours_answer_what_every_sample_answers(
    sessions: sessionmaker[Session], seed: int
) -> None:
    _random_timeline(sessions, seed)
    spans = [
        (START, END, Group.WEEK),
        (START + timedelta(days=5), START + timedelta(days=8), Group.SHIFT),  # the change
        (START + timedelta(hours=7), END - timedelta(hours=30), Group.DAY),
    ]
    for start, end, group in spans:
        with sessions.begin() as session:
            summed = report(session, CAL, MACHINES, start, end, group, now=NOW)
        with sessions.begin() as session:
            read = report(session, CAL, MACHINES, start, end, group, now=NOW, use_hours=False)
        assert [p.key for p in summed.periods] == [p.key for p in read.periods]
        for a, b in zip(summed.machines, read.machines, strict=True):
            assert _whole(a) == _whole(b)
        never = summed.machines[-1]
        # (aware datetimes in one zone subtract as wall clocks: compare in UTC)
        real = (end.astimezone(UTC) - start.astimezone(UTC)).total_seconds()
        assert never.totals.seconds[State.NO_RECORD] == real
    with sessions() as session:  # the hours were summed once, and only where there is a record
        assert session.scalar(select(func.count()).select_from(UtilizationMark)) == 3
        hours = session.scalar(select(func.count()).select_from(UtilizationHour))
        assert 0 < hours <= 3 * ((NOW - START).total_seconds() / 3600 + 6)


def test_the_time_in_each_state_is_exact_from_any_minute(sessions: sessionmaker[Session]) -> None:
    """Spans that start and end inside an hour read the cut hours from the samples."""
    _random_timeline(sessions, 3)
    start = START + timedelta(days=2, minutes=17, seconds=11)
    end = start + timedelta(days=3, hours=5, minutes=3)
    with sessions.begin() as session:
        summed = report(session, CAL, MACHINES, start, end, Group.SHIFT, now=NOW)
    with sessions.begin() as session:
        read = report(session, CAL, MACHINES, start, end, Group.SHIFT, now=NOW, use_hours=False)
    for a, b in zip(summed.machines, read.machines, strict=True):
        for fa, fb in zip([a.totals, *a.periods], [b.totals, *b.periods], strict=True):
            assert _figures(fa)[:3] == _figures(fb)[:3]
        real = (end.astimezone(UTC) - start.astimezone(UTC)).total_seconds()
        assert a.totals.total == pytest.approx(real)


def test_a_late_sample_sums_its_machine_again(sessions: sessionmaker[Session]) -> None:
    t0 = datetime(2026, 1, 5, 6, tzinfo=BERLIN)
    with sessions.begin() as session:
        session.add_all(
            [
                StatusSample(machine="m", at=t0, state="running", execution="ACTIVE"),
                StatusSample(machine="m", at=t0 + timedelta(hours=4), state="ready"),
            ]
        )
    span = (t0, t0 + timedelta(hours=8))
    now = t0 + timedelta(days=1)
    with sessions.begin() as session:
        first = report(session, CAL, ["m"], *span, Group.SHIFT, now=now)
    assert first.machines[0].totals.utilization == pytest.approx(50.0)
    # the recorder's queue reaches the database late: an alarm at 07:00-08:00
    with sessions.begin() as session:
        session.add_all(
            [
                StatusSample(machine="m", at=t0 + timedelta(hours=1), state="alarm", alarm="E1"),
                StatusSample(
                    machine="m", at=t0 + timedelta(hours=2), state="running", execution="ACTIVE"
                ),
            ]
        )
    with sessions.begin() as session:
        second = report(session, CAL, ["m"], *span, Group.SHIFT, now=now)
    m = second.machines[0]
    assert m.totals.utilization == pytest.approx(37.5)  # 3 h of 8 h
    assert [(a.text, a.seconds) for a in m.alarms] == [("E1", 3600.0)]


def test_a_machine_named_with_64_characters_has_its_stops_and_alarms(
    sessions: sessionmaker[Session],
) -> None:
    """The longest name a machine may have (PostgreSQL's identifier type holds 63 bytes: the
    names must not pass through it)."""
    name = "cell-7-" + "x" * 57
    assert len(name) == 64
    t0 = datetime(2026, 1, 5, 6, tzinfo=BERLIN)
    steps = [
        (0, "running", "ACTIVE", ""),
        (60, "alarm", "STOPPED", "1010 SPINDLE"),
        (80, "ready", "READY", ""),
        (120, "running", "ACTIVE", ""),
    ]
    with sessions.begin() as session:
        session.add_all(
            StatusSample(
                machine=name,
                at=t0 + timedelta(minutes=minute),
                state=state,
                execution=execution,
                alarm=alarm,
            )
            for minute, state, execution, alarm in steps
        )
    # a day and a half of summed hours; the samples are read only for the last hour
    span = (t0 - timedelta(hours=30), t0 + timedelta(hours=3, minutes=30))
    with sessions.begin() as session:
        r = report(session, CAL, [name], *span, Group.DAY, now=span[1] + timedelta(hours=1))
    m = r.machines[0]
    assert [(a.text, a.count, a.seconds) for a in m.alarms] == [("1010 SPINDLE", 1, 1200.0)]
    assert [(a.start, a.end) for a in m.recent_alarms] == [
        (t0 + timedelta(minutes=60), t0 + timedelta(minutes=80))
    ]
    assert [(s.start, s.end, s.state) for s in m.stops] == [
        (t0 + timedelta(minutes=60), t0 + timedelta(minutes=120), State.ALARM)
    ]
    assert m.totals.seconds[State.RUNNING] == 3600.0 + 90 * 60.0


def test_the_api_writes_the_json_the_standard_library_writes(
    sessions: sessionmaker[Session],
) -> None:
    """The API's encoder (pydantic's, for speed) gives the bytes of Starlette's JSONResponse
    (the standard library's): texts a control may send, None, whole and cut numbers."""
    _random_timeline(sessions, 4)
    odd = 'Überlast "Spindel" \\ \t\x01\x1f ✓ \u2028 </script>'
    with sessions.begin() as session:
        session.add(
            StatusSample(machine="haas-1", at=START + timedelta(hours=30), state="alarm", alarm=odd)
        )
    with sessions.begin() as session:
        r = report(session, CAL, MACHINES, START, END, Group.DAY, now=NOW)
    assert odd in {a.text for m in r.machines for a in m.alarms}
    response = answer.report_response(r)
    expected = json.dumps(
        answer.report_json(r),
        ensure_ascii=False,
        allow_nan=False,
        indent=None,
        separators=(",", ":"),
    ).encode()
    assert bytes(response.body) == expected
    assert response.media_type == "application/json"


def test_the_recorder_stores_program_part_count_and_alarm(
    sessions: sessionmaker[Session],
) -> None:
    tl = Timeline(sessions)
    t0 = datetime(2026, 1, 5, 8, tzinfo=UTC)

    def machine(execution: str, parts: int, errors: list[str] | None = None) -> MachineStatus:
        return MachineStatus(
            at=t0,
            available=True,
            execution=execution,
            mode="AUTOMATIC",
            program="O1234",
            part_count=parts,
            errors=tuple(errors or ()),
        )

    def note(status: MachineStatus, at: datetime) -> bool:
        return tl.note("vf2", status, online=True, at=at)

    assert note(machine("ACTIVE", 7), t0)
    assert note(machine("ACTIVE", 8), t0 + timedelta(minutes=1))  # a part: a sample
    assert not note(machine("ACTIVE", 8), t0 + timedelta(minutes=2))
    assert note(machine("READY", 8, ["1010 SPINDLE"]), t0 + timedelta(minutes=3))
    assert tl.flush() == 3
    with sessions() as session:
        rows = session.execute(
            select(
                StatusSample.state,
                StatusSample.program,
                StatusSample.part_count,
                StatusSample.alarm,
            ).order_by(StatusSample.id)
        ).all()
    assert [tuple(r) for r in rows] == [
        ("running", "O1234", 7, ""),
        ("running", "O1234", 8, ""),
        ("alarm", "O1234", 8, "1010 SPINDLE"),
    ]
    assert [s.part_count for s in tl.history("vf2", t0)] == [7, 8, 8]


def test_migration_0007_up_from_0004_and_back(db_url: str) -> None:
    engine: Engine = make_engine(db_url)
    try:
        migrate(engine, "0004")
        with engine.begin() as conn:
            conn.execute(
                text(
                    "INSERT INTO status_samples (machine, at, state, mode, execution) "
                    "VALUES ('m', CURRENT_TIMESTAMP, 'active', 'AUTOMATIC', 'ACTIVE')"
                )
            )
        migrate(engine, "0007")
        assert current_revision(engine) == "0007"
        columns = {c["name"] for c in inspect(engine).get_columns("status_samples")}
        assert {"program", "part_count", "alarm"} <= columns
        tables = set(inspect(engine).get_table_names())
        assert {"utilization_hours", "utilization_stretches", "utilization_marks"} <= tables
        with engine.connect() as conn:  # the old row reads with empty new fields
            row = conn.execute(
                text("SELECT state, program, part_count, alarm FROM status_samples")
            ).one()
        assert tuple(row) == ("active", "", None, "")
        migrate(engine, "0004")
        assert current_revision(engine) == "0004"
        columns = {c["name"] for c in inspect(engine).get_columns("status_samples")}
        assert columns == {"id", "machine", "at", "state", "mode", "execution"}
        assert "utilization_hours" not in inspect(engine).get_table_names()
        with engine.connect() as conn:
            assert conn.execute(text("SELECT state FROM status_samples")).scalars().all() == [
                "active"
            ]
    finally:
        engine.dispose()


def test_the_server_sums_finished_hours_in_the_background(
    sessions: sessionmaker[Session], monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    config = parse_config(
        '[[machines]]\nname = "m"\nkind = "lsv2"\nhost = "127.0.0.1"\n', base=tmp_path
    )
    t0 = datetime.now(UTC) - timedelta(hours=5)
    with sessions.begin() as session:
        session.add(StatusSample(machine="m", at=t0, state="running", execution="ACTIVE"))
    monkeypatch.setattr(component, "ROLL_EVERY", 0.05)

    async def summed() -> datetime:
        summer = component.HourSummer(sessions, [m.name for m in config.machines])
        await summer.start()
        try:
            deadline = time.monotonic() + 30
            while time.monotonic() < deadline:
                with sessions() as session:
                    mark = session.get(UtilizationMark, "m")
                if mark is not None:
                    return mark.until
                await asyncio.sleep(0.05)
            raise AssertionError("no hour was summed within 30 s")
        finally:
            await summer.stop()

    until = asyncio.run(summed())
    assert until >= datetime.now(UTC) - timedelta(hours=1, minutes=5)
    with sessions() as session:
        hours = session.scalars(
            select(UtilizationHour)
            .where(UtilizationHour.machine == "m")
            .order_by(UtilizationHour.hour)
        ).all()
    assert len(hours) >= 4
    assert all(h.running == 3600.0 for h in hours[1:])  # whole hours of running


def test_a_question_reads_while_another_transaction_writes(
    sessions: sessionmaker[Session],
) -> None:
    """The question only reads (its hour-to-slot table is temporary): a writer holding the
    database's write lock does not make it wait, and it does not make the writer wait."""
    _random_timeline(sessions, 4)
    with sessions.begin() as session:
        sum_safely(session, MACHINES, NOW)
    started = time.monotonic()
    with sessions.begin() as writer:  # on SQLite: BEGIN IMMEDIATE, the write lock
        writer.add(StatusSample(machine="tnc-1", at=NOW, state="ready", execution="READY"))
        writer.flush()
        with read_only(sessions)() as reader:
            r = report(reader, CAL, MACHINES, START, END, Group.WEEK, now=NOW, sum_first=False)
    assert time.monotonic() - started < 10  # the busy timeout would be the tell
    assert r.machines[0].totals.total > 0
    with sessions() as session:
        assert session.scalar(select(func.count()).select_from(StatusSample)) > 0
