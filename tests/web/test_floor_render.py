"""What the cards and pages say about times and jobs: the shop's clock with its zone, the
timeline's axis, a job's rate and time left, a card built from the typed status and state."""

from __future__ import annotations

from dataclasses import replace
from datetime import UTC, datetime, timedelta
from zoneinfo import ZoneInfo

import pytest
from hypothesis import given
from hypothesis import strategies as st

from tests.peers import require_module

require_module("jinja2")
require_module("pygments")

from opendnc.server.core.state import State  # noqa: E402
from opendnc.server.core.status import MachineStatus  # noqa: E402
from opendnc.server.web import render  # noqa: E402

BERLIN = ZoneInfo("Europe/Berlin")
WINTER = datetime(2026, 1, 5, 13, 2, 31, tzinfo=UTC)  # 14:02:31 CET
SUMMER = datetime(2026, 7, 6, 12, 2, 31, tzinfo=UTC)  # 14:02:31 CEST


def test_times_are_on_the_shops_clock_with_the_zone() -> None:
    assert render.when(WINTER, BERLIN) == "2026-01-05 14:02:31 CET"
    assert render.when(SUMMER, BERLIN) == "2026-07-06 14:02:31 CEST"
    assert render.when("2026-01-05T13:02:31+00:00") == "2026-01-05 13:02:31 UTC"
    assert render.when(None) == ""
    assert render.iso(WINTER, BERLIN) == "2026-01-05T14:02:31+01:00"
    assert render.iso(SUMMER, BERLIN) == "2026-07-06T14:02:31+02:00"
    # today: the clock only; another day: with the date (the shop's day, not UTC's)
    assert render.clock(WINTER, BERLIN, now=WINTER + timedelta(hours=2)) == "14:02 CET"
    late = datetime(2026, 1, 5, 23, 30, tzinfo=UTC)  # 00:30 on the 6th in Berlin
    assert render.clock(late, BERLIN, now=late) == "00:30 CET"
    assert render.clock(late, BERLIN, now=late - timedelta(hours=1)) == "2026-01-06 00:30 CET"
    stamp = str(render.stamp(WINTER, BERLIN))
    assert 'datetime="2026-01-05T14:02:31+01:00"' in stamp
    assert "<span>2026-01-05</span> <span>14:02:31 CET</span>" in stamp


def test_the_timeline_axis_names_the_hours_of_the_shops_clock() -> None:
    end = datetime(2026, 1, 5, 13, 40, tzinfo=UTC)  # 14:40 CET
    ticks = render.axis_ticks(end - timedelta(hours=4), end, BERLIN)
    assert [t.label for t in ticks] == ["10:40", "11:00", "12:00", "13:00", "14:00", "14:40 CET"]
    # 11:00 is 20 minutes into four hours
    assert ticks[1].left == pytest.approx(100 * 20 / 240, abs=0.01)
    assert ticks[0].left == 0
    assert ticks[-1].left == 100
    assert ticks[1].iso == "2026-01-05T11:00:00+01:00"
    # an hour mark too near an end is left out (its label would cover the end's)
    close = datetime(2026, 1, 5, 13, 5, tzinfo=UTC)  # 14:05 CET: 14:00 is 2 % from the end
    labels = [t.label for t in render.axis_ticks(close - timedelta(hours=4), close, BERLIN)]
    assert labels == ["10:05", "11:00", "12:00", "13:00", "14:05 CET"]


def test_the_night_the_clocks_go_back_has_its_hours_once_each() -> None:
    end = datetime(2026, 10, 25, 3, 45, tzinfo=UTC)  # 04:45 CET, the night of the change
    labels = [t.label for t in render.axis_ticks(end - timedelta(hours=4), end, BERLIN)]
    # 01:45 CEST ... 02:00 CEST, 02:00 CET, 03:00, 04:00 ... 04:45 CET: five real hours
    assert labels == ["01:45", "02:00", "02:00", "03:00", "04:00", "04:45 CET"]


def test_a_jobs_rate_and_time_left_follow_from_its_bytes_and_start() -> None:
    start = datetime(2026, 1, 5, 8, 0, tzinfo=UTC)
    # 24 kB in 2 s of 144 kB: 12 kB/s, 120 kB left take 10 s
    assert render.job_pace(24_000, 144_000, start, start + timedelta(seconds=2)) == (
        "12.0 kB/s",
        "about 10 s left",
    )
    # 1 MB of 10 MB in 100 s: 10 kB/s, 9 MB left take 900 s
    assert render.job_pace(1_000_000, 10_000_000, start, start + timedelta(seconds=100)) == (
        "10.0 kB/s",
        "about 15 min left",
    )
    assert render.job_pace(0, 100, start, start + timedelta(seconds=5)) == ("", "")
    assert render.job_pace(10, 100, None, start) == ("", "")
    assert render.job_pace(100, None, start, start + timedelta(seconds=10)) == ("10 B/s", "")


def test_the_time_left_is_measured_from_the_first_bytes_not_the_wait_before_them() -> None:
    """A 9 s load first said "about 5 min 13 s left": the control's start (a Haas's NAK
    every few seconds) counted as transfer time."""
    start = datetime(2026, 1, 5, 8, 0, tzinfo=UTC)
    first = (start + timedelta(seconds=3), 1_000)  # 3 s waiting for the control, then bytes
    total = 100_000  # 100 kB at 16.5 kB/s: 6 s of transfer
    soon = start + timedelta(seconds=3.5)
    assert render.job_pace(9_250, total, start, soon, first) == ("", "")  # too early to say
    at = start + timedelta(seconds=5)
    rate, left = render.job_pace(34_000, total, start, at, first)
    assert (rate, left) == ("16.5 kB/s", "about 4 s left")
    # what the rate from the job's start would have said
    assert render.job_pace(34_000, total, start, at)[1] == "about 10 s left"


@given(st.floats(min_value=0, max_value=10 * 86400, allow_nan=False))
def test_a_duration_reads_as_two_units_at_most(seconds: float) -> None:
    text = render.duration(seconds)
    parts = text.split()
    assert len(parts) in (2, 4)
    assert parts[1] in ("s", "min", "h")
    total = {"s": 1, "min": 60, "h": 3600}
    value = sum(int(n) * total[u] for n, u in zip(parts[::2], parts[1::2], strict=True))
    # what is dropped is less than the smallest unit said
    assert 0 <= round(seconds) - value < total[parts[-1]]


def test_a_card_tells_the_job_the_feed_line_parts_tool_overrides_and_last_job() -> None:
    now = datetime(2026, 1, 5, 13, 2, 40, tzinfo=UTC)
    status = MachineStatus(
        datetime(2026, 1, 5, 13, 2, 31, tzinfo=UTC),
        True,
        execution="ACTIVE",
        mode="AUTOMATIC",
        program="O01000",
        part_count=17,
        tool=4,
        overrides={"feed": 90.0, "spindle": 100.0},
    )
    job = render.RunningJob(
        7,
        "",
        30_000,
        60_000,
        started=datetime(2026, 1, 5, 13, 2, 10, tzinfo=UTC),  # 30 s before now: 1 kB/s
        line=(1200, 2400),
    )
    since = datetime(2026, 1, 5, 12, 30, tzinfo=UTC)
    seen = render.Seen("haas-1", "haas_ngc", status, State.RUNNING, True, since=since, job=job)
    last = render.LastJob("send O01000.nc v2", "failed", now - timedelta(hours=1), "timeout")
    c = render.card(seen, job_label="dripfeed O01000.nc v2", last_job=last, zone=BERLIN, now=now)
    assert (c.percent, c.rate, c.left) == (50, "1.0 kB/s", "about 30 s left")
    assert c.job_label == "dripfeed O01000.nc v2"
    assert (c.feed_line, c.feed_lines) == (1200, 2400)
    assert (c.parts, c.tool) == (17, 4)
    assert c.overrides == "feed 90\u00a0%, spindle 100\u00a0%"
    assert (c.updated, c.updated_iso) == ("14:02 CET", "2026-01-05T14:02:00+01:00")
    assert c.since == "13:30 CET"
    assert c.last_job_at == "13:02 CET"
    html = render.render("_card.html", c=c, whole=False, zone=BERLIN)
    for text in ("line 1200 of 2400", "T4", "17", "about 30 s left", "timeout", "failed"):
        assert text in html, text
    # the card changes once a minute, not at every poll of the same minute
    later = replace(seen, status=replace(status, at=datetime(2026, 1, 5, 13, 2, 59, tzinfo=UTC)))
    again = render.card(later, job_label=c.job_label, last_job=last, zone=BERLIN, now=now)
    assert render.render("_card.html", c=again, whole=False, zone=BERLIN) == html


def test_a_control_that_is_offline_or_silent_reports_no_parts_tool_or_overrides() -> None:
    status = MachineStatus(datetime(2026, 1, 5, 13, 2, 31, tzinfo=UTC), False, tool=3)
    c = render.card(render.Seen("haas-serial-1", "haas_serial", status, State.UNKNOWN, True))
    assert (c.parts, c.tool, c.overrides) == (None, None, "")
    html = render.render("_card.html", c=c, whole=False)
    for word in ("Tool", "Parts", "Overrides"):
        assert word not in html


def test_a_controls_path_wraps_after_a_folder_never_inside_a_name() -> None:
    assert str(render.breakable_path("TNC:/nc_prog/POCKET.H")) == "TNC:/<wbr>nc_prog/<wbr>POCKET.H"
    assert str(render.breakable_path("C:\\a<b>")) == "C:\\<wbr>a&lt;b&gt;"  # escaped, then marked


def test_the_send_panel_lists_every_error_its_count_says() -> None:
    """The send panel said "tnc-1 2 errors" and listed one."""
    problems = [
        {"severity": "error", "line": 3, "message": "G02 without a radius"},
        {"severity": "warning", "line": 4, "message": "no coolant"},
        {"severity": "error", "line": 9, "message": "X beyond the travel"},
    ]
    check = {"machine": "tnc-1", "version": 2, "ok": False, "errors": 2, "warnings": 1}
    html = render.render(
        "_machine_checks.html", checks=[{**check, "problems": problems}], program="P.nc"
    )
    assert "2 errors" in html
    for text in ("P.nc:3</a> G02 without a radius", "P.nc:9</a> X beyond the travel"):
        assert text in html, html
    assert "no coolant" not in html  # the warnings are counted, the check page lists them


@pytest.mark.parametrize(
    ("state", "execution", "said"),
    [
        ("running", "ACTIVE", "Running since"),
        ("alarm", "STOPPED", "Alarm since"),
        ("stopped", "FEED_HOLD", "Stopped, feed hold since"),
        ("stopped", "STOPPED", "Stopped since"),
        ("ready", "PROGRAM_COMPLETED", "Ready, program completed since"),
    ],
)
def test_a_card_says_its_state_in_plain_words(state: str, execution: str, said: str) -> None:
    """Not "Running (active)" or "Alarm (stopped)": the execution word only where it adds."""
    status = MachineStatus(WINTER, True, execution=execution)
    since = datetime(2026, 1, 5, 12, 30, tzinfo=UTC)
    seen = render.Seen("tnc-1", "lsv2", status, State(state), True, since=since)
    c = render.card(seen, zone=BERLIN, now=WINTER)
    html = render.render("_card.html", c=c, whole=False, zone=BERLIN)
    line = html.split('<p class="since small">')[1].split("<time")[0].strip()
    assert line == said
