"""Today's Gantt row on /utilization: the slices recorded so far end at now, and the row is
the whole day, so the states end where now is on the row (noon: half of it), not stretched
to midnight."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

from opendnc.server.core.shifts import Calendar, Period
from opendnc.server.core.state import State
from opendnc.server.utilization.collect import Figures
from opendnc.server.web.pages.utilization import gantt_rows


def _running(seconds: float) -> Figures:
    f = Figures()
    f.seconds[State.RUNNING] = seconds
    return f


def test_todays_states_end_at_now_on_the_days_row() -> None:
    midnight = datetime(2026, 1, 5, tzinfo=UTC)
    hour = timedelta(hours=1)
    # twelve hours recorded (midnight to noon, "now"), all running
    slices = [Period(f"h{i}", midnight + i * hour, midnight + (i + 1) * hour) for i in range(12)]
    figures = {"m": [_running(3600.0) for _ in slices]}
    (row,) = gantt_rows(Calendar(), ["m"], slices, figures, (midnight, midnight + 24 * hour))
    (segment,) = row.segments
    assert (segment.state, segment.x, segment.width) == ("running", 0.0, 50.0)
    # without the day's span (a finished span): the slices are the whole row
    (whole,) = gantt_rows(Calendar(), ["m"], slices, figures)
    assert whole.segments[0].width == 100.0
