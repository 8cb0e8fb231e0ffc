"""Utilization ends at now: a span that holds now is counted up to now (the state in force is
not stretched to the span's end), a stop still going on lasts until now, and percentages are
over the time that has passed. The timeline is written directly and asked at a known now."""

from __future__ import annotations

from datetime import datetime, timedelta
from zoneinfo import ZoneInfo

from sqlalchemy.orm import Session, sessionmaker

from opendnc.server.core.shifts import parse_calendar
from opendnc.server.core.state import State
from opendnc.server.store.models import StatusSample
from opendnc.server.utilization.answer import report_json
from opendnc.server.utilization.collect import Group, report
from opendnc.server.utilization.sums import Point, summarize
from tests.server.conftest import on

BERLIN = ZoneInfo("Europe/Berlin")
CAL = parse_calendar({"server": {"timezone": "Europe/Berlin"}})  # every hour scheduled
DAY = datetime(2026, 1, 5, tzinfo=BERLIN)  # a Monday
T0 = datetime(2026, 1, 5, 14, 0, tzinfo=BERLIN)
NOW = T0 + timedelta(minutes=2)

# (machine, minutes from T0, state, execution): "ran" was ready for three hours, then started
# two minutes before now; "halted" ran, then stopped eight minutes before T0 and still is
STEPS = [
    ("ran", -180, "ready", "READY"),
    ("ran", 0, "running", "ACTIVE"),
    ("halted", -60, "running", "ACTIVE"),
    ("halted", -8, "ready", "READY"),
]


def _write(sessions: sessionmaker[Session]) -> None:
    with sessions.begin() as session:
        session.add_all(
            StatusSample(
                machine=machine, at=T0 + timedelta(minutes=minutes), state=state, execution=ex
            )
            for machine, minutes, state, ex in STEPS
        )


@on("sqlite")
def test_a_machine_that_ran_two_minutes_ran_two_minutes(sessions: sessionmaker[Session]) -> None:
    _write(sessions)
    with sessions.begin() as session:
        r = report(session, CAL, ["ran", "halted"], DAY, DAY + timedelta(days=1), now=NOW)
    ran, halted = r.machines
    elapsed = (NOW - DAY).total_seconds()
    assert ran.totals.seconds[State.RUNNING] == 120.0
    assert ran.totals.seconds[State.READY] == 3 * 3600.0
    assert ran.totals.total == elapsed  # nothing counted after now
    assert ran.totals.utilization_recorded == 100.0 * 120 / (3 * 3600 + 120)
    assert ran.totals.utilization == 100.0 * 120 / elapsed  # shift time that has passed
    # the stop of ten minutes is ten minutes, and still going on at now
    (stop,) = halted.stops
    assert (stop.start, stop.end, stop.ongoing) == (T0 - timedelta(minutes=8), NOW, True)
    assert halted.totals.seconds[State.READY] == 600.0
    data = report_json(r)
    assert data["until"] == "2026-01-05T14:02:00+01:00"  # the figures end at now
    assert data["machines"][0]["totals"]["seconds"]["running"] == 120.0
    assert data["machines"][1]["stops"][0]["seconds"] == 600.0


@on("sqlite")
def test_the_days_after_now_are_empty(sessions: sessionmaker[Session]) -> None:
    _write(sessions)
    with sessions.begin() as session:
        r = report(session, CAL, ["ran"], DAY, DAY + timedelta(days=7), Group.DAY, now=NOW)
    (ran,) = r.machines
    assert [round(f.total) for f in ran.periods] == [round((NOW - DAY).total_seconds())] + [0] * 6
    assert [f.utilization for f in ran.periods[1:]] == [None] * 6
    assert ran.totals.seconds[State.RUNNING] == 120.0


def test_the_reference_also_ends_at_now() -> None:
    points = [
        Point(T0 + timedelta(minutes=m), State.READY if s == "ready" else State.RUNNING)
        for machine, m, s, _ex in STEPS
        if machine == "ran"
    ]
    _periods, ran = summarize("ran", points, CAL, Group.DAY, DAY, DAY + timedelta(days=1), now=NOW)
    assert ran.totals.seconds[State.RUNNING] == 120.0
    assert ran.totals.total == (NOW - DAY).total_seconds()


@on("sqlite")
def test_a_span_after_now_counts_nothing(sessions: sessionmaker[Session]) -> None:
    _write(sessions)
    later = DAY + timedelta(days=3)
    with sessions.begin() as session:
        r = report(session, CAL, ["ran", "halted"], later, later + timedelta(days=2), now=NOW)
    for m in r.machines:
        assert m.totals.total == 0.0
        assert m.stops == []
    assert r.until == later
