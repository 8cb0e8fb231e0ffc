"""Property tests: the shift calendar parser and the utilization API's time parser give typed
errors only, and every shift period of a valid calendar is a positive stretch that the zone's
clock changes lengthen or shorten by at most an hour."""

from __future__ import annotations

import contextlib
from datetime import UTC, datetime, timedelta

from hypothesis import given
from hypothesis import strategies as st

from opendnc.errors import InputError
from opendnc.server.core.shifts import DAYS, parse_calendar
from opendnc.server.utilization.answer import parse_when

scalars = st.one_of(st.none(), st.booleans(), st.integers(), st.text(max_size=12))
clocks = st.one_of(
    st.from_regex(r"([01]\d|2[0-4]):[0-6]\d", fullmatch=True), st.text(max_size=6), scalars
)
days = st.one_of(
    st.lists(st.sampled_from([*DAYS, "mon-fri", "sat-sun", "fri-mon", "xx", "mon-"]), max_size=4),
    scalars,
)
shifts = st.fixed_dictionaries(
    {"name": st.one_of(st.text(max_size=8), scalars), "start": clocks, "end": clocks},
    optional={"days": days, "extra": scalars},
)
zones = st.sampled_from(
    ["Europe/Berlin", "UTC", "America/New_York", "Asia/Kolkata", "Nowhere/X", ""]
)


@given(zones, st.one_of(st.lists(shifts, max_size=4), scalars))
def test_calendar_parser_only_input_errors(zone: str, items: object) -> None:
    with contextlib.suppress(InputError):
        cal = parse_calendar({"server": {"timezone": zone}, "shifts": items})
        start = datetime(2026, 3, 20, tzinfo=UTC)
        end = start + timedelta(days=14)  # the European spring change is inside
        for period in cal.shift_periods(start, end):
            assert period.end > period.start
            hours = period.seconds / 3600
            assert 0 < hours <= 25


@given(st.text(max_size=40))
def test_time_parser_only_input_errors(text: str) -> None:
    cal = parse_calendar({"server": {"timezone": "Europe/Berlin"}})
    with contextlib.suppress(InputError):
        at = parse_when(text, cal, "from")
        assert at.tzinfo is not None
