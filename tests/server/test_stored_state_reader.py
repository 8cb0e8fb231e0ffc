"""One reader of stored state words: the status timeline and utilization read the same stored
sample as the same state, old words included (docs/server.md#status-samples)."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import pytest
from sqlalchemy.orm import Session, sessionmaker

from opendnc.server.core.shifts import parse_calendar
from opendnc.server.core.state import State
from opendnc.server.machines.timeline import Timeline
from opendnc.server.store.models import StatusSample
from opendnc.server.utilization.collect import Group, report
from tests.server.conftest import on

T0 = datetime(2026, 3, 2, 8, tzinfo=UTC)  # a Monday, on the full hour
HOUR = timedelta(hours=1)


@on("sqlite")
@pytest.mark.parametrize(
    ("word", "execution", "expected"),
    [
        # written before the one classifier: a reachable control that said no execution word
        # was filed as "ready"; today such a control is unknown (what it said decides)
        ("ready", "", State.UNKNOWN),
        ("ready", "READY", State.READY),  # the classifier's own ready
        ("active", "ACTIVE", State.RUNNING),  # the old word for running
        ("none", "", State.NO_RECORD),  # the old word for no record
        ("stopped", "FEED_HOLD", State.STOPPED),
        ("idle", "", State.UNKNOWN),  # a word this server never wrote
    ],
)
def test_the_timeline_and_utilization_read_a_stored_sample_alike(
    sessions: sessionmaker[Session], word: str, execution: str, expected: State
) -> None:
    machine = "m"
    with sessions.begin() as session:
        session.add_all(
            [
                StatusSample(machine=machine, at=T0, state=word, execution=execution),
                StatusSample(machine=machine, at=T0 + HOUR, state="none", execution=""),
            ]
        )

    # the timeline's path: the strip of the hour the sample holds
    strip = Timeline(sessions).segments(machine, hours=1, now=T0 + HOUR)
    assert [s.state for s in strip] == [expected.value]

    # utilization's path: the hour, finished and summed, then read from the summed hours
    calendar = parse_calendar({})  # no shifts: every hour is scheduled
    with sessions.begin() as session:
        r = report(session, calendar, [machine], T0, T0 + HOUR, Group.DAY, now=T0 + 3 * 24 * HOUR)
    seconds = r.machines[0].totals.seconds
    assert {s: v for s, v in seconds.items() if v} == {expected: 3600.0}
