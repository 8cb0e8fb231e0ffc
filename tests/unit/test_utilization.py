"""Utilization from a timeline the test writes: known states and durations give known figures
(worked out by hand in the comments), across shift boundaries, an overnight shift, the days
the clocks change, gaps without a record and a machine without any sample."""

from __future__ import annotations

import itertools
import tomllib
from datetime import UTC, datetime
from pathlib import Path
from zoneinfo import ZoneInfo

import pytest

from opendnc.server.config.shop import ConfigError, parse_config
from opendnc.server.core.shifts import Calendar, CalendarError, parse_calendar
from opendnc.server.core.state import State, from_stored
from opendnc.server.utilization.collect import Group, Point, summarize

BERLIN = ZoneInfo("Europe/Berlin")
H = 3600.0


def at(day: int, hour: int, minute: int = 0, month: int = 1) -> datetime:
    """A Berlin wall-clock time in 2026."""
    return datetime(2026, month, day, hour, minute, tzinfo=BERLIN)


def calendar(*shifts: tuple[str, str, str, list[str]]) -> Calendar:
    return parse_calendar(
        {
            "server": {"timezone": "Europe/Berlin"},
            "shifts": [{"name": n, "start": a, "end": b, "days": days} for n, a, b, days in shifts],
        }
    )


THREE = calendar(
    ("early", "06:00", "14:00", ["mon-fri"]),
    ("late", "14:00", "22:00", ["mon-fri"]),
    ("night", "22:00", "06:00", ["mon-fri"]),
)
R, RD, ST, AL, OFF, NR = (
    State.RUNNING,
    State.READY,
    State.STOPPED,
    State.ALARM,
    State.OFFLINE,
    State.NO_RECORD,
)
# Monday 5 January 2026 (winter, UTC+1)
MILL = [
    Point(at(5, 6), RD),
    Point(at(5, 7), R),
    Point(at(5, 9), RD),
    Point(at(5, 9, 30), AL, alarm="1010 SPINDLE OVERLOAD"),
    Point(at(5, 10), R),
    Point(at(5, 12), ST),
    Point(at(5, 12, 30), R),
    Point(at(5, 13), RD),
    Point(at(5, 14), OFF),
    Point(at(5, 15), NR),
]


def test_known_states_give_known_figures_per_shift() -> None:
    periods, m = summarize("mill-1", MILL, THREE, Group.SHIFT, at(5, 0), at(6, 0))
    assert [p.key for p in periods] == ["2026-01-05 early", "2026-01-05 late", "2026-01-05 night"]
    early, late, night = m.periods
    # early 06-14: running 07-09, 10-12, 12:30-13 = 4.5 h of 8 h
    assert early.utilization == pytest.approx(56.25)
    assert early.seconds[R] == 4.5 * H
    assert early.seconds[RD] == 2.5 * H  # 06-07, 09-09:30, 13-14
    assert early.seconds[AL] == early.seconds[ST] == 0.5 * H
    # late 14-22: offline 14-15, then no record (the server stopped)
    assert late.seconds[OFF] == 1 * H
    assert late.seconds[NR] == 7 * H
    assert late.utilization == 0.0
    assert late.utilization_recorded == 0.0
    # night: only 22-24 of it lies in the span
    assert night.total == 2 * H
    assert night.seconds[NR] == 2 * H
    assert night.utilization_recorded is None
    # runs: 07-09 ended by ready (2 h); 10-13 with a 30 min feed hold (2.5 h running)
    assert m.totals.runs == 2
    assert m.totals.cycle_mean == pytest.approx(2.25 * H)
    assert m.totals.parts is None  # no counter
    # 00-06 on Monday is no shift (Sunday's night is not worked): 18 h of shift time
    assert m.totals.scheduled_total == 18 * H
    assert m.totals.utilization == pytest.approx(25.0)
    assert m.totals.utilization_recorded == pytest.approx(50.0)  # 4.5 h of 06-15
    assert m.totals.total == 24 * H


def test_stops_are_joined_named_by_their_worst_state_and_alarms_keep_their_text() -> None:
    _periods, m = summarize("mill-1", MILL, THREE, Group.DAY, at(5, 0), at(6, 0))
    stops = [(s.start, s.seconds / H, s.state, s.text) for s in m.stops]
    assert stops == [
        (at(5, 13), 2.0, OFF, ""),  # ready 13-14 then offline until the server stopped
        (at(5, 6), 1.0, RD, ""),
        (at(5, 9), 1.0, AL, "1010 SPINDLE OVERLOAD"),  # ready, then the alarm
        (at(5, 12), 0.5, ST, ""),
    ]
    assert [(a.text, a.count, a.seconds) for a in m.alarms] == [
        ("1010 SPINDLE OVERLOAD", 1, 0.5 * H)
    ]


def test_a_pause_shorter_than_five_minutes_is_no_stop() -> None:
    points = [Point(at(5, 6), R), Point(at(5, 7), RD), Point(at(5, 7, 4), R)]
    _p, m = summarize("m", points, THREE, Group.DAY, at(5, 6), at(5, 8))
    assert m.stops == []
    assert m.totals.seconds[RD] == 4 * 60


def test_a_stretch_across_a_shift_boundary_is_split_there() -> None:
    points = [Point(at(6, 13), R), Point(at(6, 15), RD)]
    _p, m = summarize("m", points, THREE, Group.SHIFT, at(6, 12), at(6, 16))
    early, late = m.periods
    assert early.seconds[R] == late.seconds[R] == 1 * H
    assert early.utilization == pytest.approx(50.0)  # 12-14 in the span: 1 h of 2 h
    assert late.utilization == pytest.approx(50.0)  # 14-16: 1 h of 2 h


def test_an_overnight_shift_ends_the_next_day() -> None:
    night = calendar(("night", "22:00", "06:00", ["mon"]))
    points = [Point(at(5, 23), R), Point(at(6, 5), RD)]
    periods, m = summarize("m", points, night, Group.SHIFT, at(5, 0), at(7, 0))
    assert [(p.key, p.seconds) for p in periods] == [("2026-01-05 night", 8 * H)]
    assert m.periods[0].utilization == pytest.approx(75.0)  # 6 h of 8 h
    _p, by_day = summarize("m", points, night, Group.DAY, at(5, 0), at(7, 0))
    monday, tuesday = by_day.periods
    assert monday.scheduled_total == 2 * H
    assert monday.utilization == pytest.approx(50.0)
    assert tuesday.scheduled_total == 6 * H  # 00-06 of Monday's night
    assert tuesday.utilization == pytest.approx(5 / 6 * 100)


def test_the_spring_change_shortens_the_night_and_the_day() -> None:
    # 29 March 2026: 02:00 CET becomes 03:00 CEST
    night = calendar(("night", "22:00", "06:00", ["sat"]))
    points = [Point(at(28, 21, month=3), R), Point(at(29, 7, month=3), RD)]
    periods, m = summarize("m", points, night, Group.SHIFT, at(28, 0, month=3), at(30, 0, month=3))
    assert [p.seconds for p in periods] == [7 * H]
    assert m.periods[0].seconds[R] == 7 * H
    assert m.periods[0].utilization == 100.0
    days, by_day = summarize("m", points, night, Group.DAY, at(28, 0, month=3), at(30, 0, month=3))
    assert [d.key for d in days] == ["2026-03-28", "2026-03-29"]
    assert [f.total for f in by_day.periods] == [24 * H, 23 * H]
    assert by_day.periods[1].seconds[R] == 6 * H  # 00:00-07:00 local is 6 real hours


def test_the_autumn_change_lengthens_the_night_and_the_day() -> None:
    # 25 October 2026: 03:00 CEST becomes 02:00 CET
    night = calendar(("night", "22:00", "06:00", ["sat"]))
    points = [Point(at(24, 22, month=10), R), Point(at(25, 6, month=10), RD)]
    periods, m = summarize(
        "m", points, night, Group.SHIFT, at(24, 0, month=10), at(26, 0, month=10)
    )
    assert [p.seconds for p in periods] == [9 * H]
    assert m.periods[0].utilization == 100.0
    _d, by_day = summarize("m", points, night, Group.DAY, at(25, 0, month=10), at(26, 0, month=10))
    assert by_day.periods[0].total == 25 * H


def test_a_server_stop_is_no_record_and_ends_a_run_uncounted() -> None:
    points = [Point(at(5, 8), R), Point(at(5, 10), NR), Point(at(5, 11), R), Point(at(5, 12), RD)]
    _p, m = summarize("m", points, THREE, Group.DAY, at(5, 8), at(5, 13))
    assert m.totals.seconds[NR] == 1 * H
    assert m.totals.utilization_recorded == pytest.approx(75.0)  # 3 h of 4 h recorded
    assert m.totals.utilization == pytest.approx(60.0)  # 3 h of the 5 h of shift
    assert m.totals.runs == 1  # 08-10 was cut by the stop; 11-12 ended at ready
    assert m.totals.cycle_mean == 1 * H
    # no record is not a stop; the ready hour at the end still goes on
    assert [(s.start, s.state, s.ongoing) for s in m.stops] == [(at(5, 12), RD, True)]


def test_a_machine_without_samples_has_no_record() -> None:
    _p, m = summarize("m", [], THREE, Group.DAY, at(5, 0), at(6, 0))
    assert m.totals.seconds[NR] == 24 * H
    assert m.totals.utilization == 0.0  # its shift time passed without running
    assert m.totals.utilization_recorded is None
    assert m.totals.parts is None
    assert m.totals.runs == 0
    assert m.stops == m.alarms == []


def test_parts_from_a_counter_that_is_reset() -> None:
    # a Haas counts at M30, the end of the cycle: 30 min runs from 08:00, 09:00, ...
    counts = [5, 6, 7, 0, 1]
    points = []
    for k, (before, after) in enumerate(itertools.pairwise(counts)):
        points += [Point(at(5, 8 + k), R, part_count=before)]
        points += [Point(at(5, 8 + k, 30), RD, part_count=after)]
    _p, m = summarize("m", points, THREE, Group.DAY, at(5, 0), at(6, 0))
    # 5 -> 6 -> 7 (+2), reset to 0 (+0), -> 1 (+1)
    assert m.totals.parts == 3
    # the run that ended with the reset is not known to have made a part
    assert m.totals.runs == 3
    assert m.totals.cycle_mean == 0.5 * H


def test_without_shifts_every_hour_is_shift_time() -> None:
    points = [Point(at(5, 0), R), Point(at(5, 6), RD)]
    _p, m = summarize("m", points, Calendar(BERLIN), Group.DAY, at(5, 0), at(6, 0))
    assert m.totals.utilization == pytest.approx(25.0)


def test_weeks_are_iso_weeks_from_monday_midnight() -> None:
    points = [Point(at(4, 12), R)]
    weeks, m = summarize("m", points, THREE, Group.WEEK, at(4, 0), at(13, 0))
    assert [w.key for w in weeks] == ["2026-W01", "2026-W02", "2026-W03"]
    assert weeks[1].start == at(5, 0).astimezone(UTC)
    assert [f.seconds[R] for f in m.periods] == [12 * H, 7 * 24 * H, 24 * H]


@pytest.mark.parametrize(
    ("state", "execution", "expected"),
    [
        ("active", "ACTIVE", State.RUNNING),  # written before the one classifier
        ("none", "", State.NO_RECORD),
        ("ready", "", State.UNKNOWN),  # a control that said nothing was filed as ready
        ("ready", "READY", State.READY),
        ("running", "ACTIVE", State.RUNNING),
        ("no_record", "", State.NO_RECORD),
        ("something", "", State.UNKNOWN),
    ],
)
def test_stored_states_in_the_classifiers_words(
    state: str, execution: str, expected: State
) -> None:
    assert from_stored(state, execution) is expected


def test_shift_and_zone_configuration() -> None:
    config = parse_config(
        """
        [server]
        timezone = "Europe/Berlin"
        [[shifts]]
        name = "weekend"
        days = ["sat", "sun"]
        start = "08:00"
        end = "24:00"
        """,
        base=Path("."),
    )
    cal = config.calendar
    assert cal.zone_name == "Europe/Berlin"
    (shift,) = cal.shifts
    assert shift.days == frozenset({5, 6})
    assert shift.overnight
    (period,) = cal.shift_periods(at(10, 0), at(11, 0))
    assert period.end == at(11, 0).astimezone(UTC)
    assert period.seconds == 16 * H
    assert parse_config("", base=Path(".")).calendar.zone_name == "UTC"


@pytest.mark.parametrize(
    ("text", "key"),
    [
        ('[server]\ntimezone = "Mars/Olympus"', "server.timezone"),
        ('[[shifts]]\nname = "a"\nstart = "6:00"\nend = "25:00"', "shifts[0].end"),
        ('[[shifts]]\nname = "a"\nstart = "06:00"\nend = "06:00"', "shifts[0].end"),
        (
            '[[shifts]]\nname = "a"\nstart = "06:00"\nend = "14:00"\ndays = ["mo-fr"]',
            "shifts[0].days",
        ),
        ('[[shifts]]\nname = "a"\nstart = "06:00"\nend = "14:00"\nbreak = 30', "shifts[0].break"),
        (
            '[[shifts]]\nname = "a"\nstart = "06:00"\nend = "14:00"\n'
            '[[shifts]]\nname = "A"\nstart = "14:00"\nend = "22:00"',
            "shifts[1].name",
        ),
    ],
)
def test_a_bad_calendar_names_its_key(text: str, key: str) -> None:
    with pytest.raises(ConfigError) as caught:
        parse_config(text, base=Path("."))
    assert caught.value.key == key
    assert str(caught.value) == str(caught.value).strip()
    assert "\n" not in str(caught.value)
    raw = tomllib.loads(text)
    with pytest.raises(CalendarError):
        parse_calendar(raw)
