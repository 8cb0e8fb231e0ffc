"""The status timeline's bookkeeping: changes only, placed on a strip over a time window."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import pytest

from tests.peers import require_module

require_module("jinja2")

from opendnc.server.core.status import MachineStatus  # noqa: E402
from opendnc.server.machines.timeline import Timeline  # noqa: E402
from tests.server.test_status_timeline import note as _note  # noqa: E402

T0 = datetime(2026, 1, 5, 8, 0, tzinfo=UTC)


def test_only_changes_are_kept_and_segments_fill_the_window() -> None:
    tl = Timeline()
    _note(tl, "m", T0, "READY")
    _note(tl, "m", T0 + timedelta(minutes=5), "READY")  # no change: not kept
    _note(tl, "m", T0 + timedelta(hours=1), "ACTIVE")
    _note(tl, "m", T0 + timedelta(hours=3), "", online=False)
    assert len(tl.changes["m"]) == 3
    segments = tl.segments("m", hours=4, width=400, now=T0 + timedelta(hours=4))
    assert [(s.x, s.width, s.state) for s in segments] == [
        (0.0, 100.0, "ready"),
        (100.0, 200.0, "running"),
        (300.0, 100.0, "offline"),
    ]
    assert segments[1].label == "running, active, automatic"
    # each stretch knows its bounds (its title on the page says them on the shop's clock)
    assert (segments[1].start, segments[1].end) == (
        T0 + timedelta(hours=1),
        T0 + timedelta(hours=3),
    )


def test_what_began_before_the_window_is_cut_at_its_start() -> None:
    tl = Timeline()
    _note(tl, "m", T0, "STOPPED")
    segments = tl.segments("m", hours=1, width=100, now=T0 + timedelta(hours=3))
    assert [(s.x, s.width, s.state) for s in segments] == [(0.0, 100.0, "stopped")]
    assert segments[0].start == T0 + timedelta(hours=2)  # cut at the window's start
    assert tl.segments("other", now=T0) == []


@pytest.mark.parametrize(
    ("status", "online", "state"),
    [
        (MachineStatus(T0, True, execution="READY", errors=("E1",)), True, "alarm"),
        (MachineStatus(T0, True, execution="INTERRUPTED"), True, "stopped"),
        (None, False, "offline"),
        # a serial Haas without MDC: reachable, but it says nothing
        (MachineStatus(T0, True), True, "unknown"),
    ],
)
def test_states(status: MachineStatus | None, online: bool, state: str) -> None:
    tl = Timeline()
    tl.note("m", status, online=online, at=T0)
    assert tl.segments("m", hours=1, now=T0 + timedelta(minutes=1))[0].state == state


def test_samples_written_before_the_classifier_read_as_its_states() -> None:
    # Stored history said "active" for running and "none" for no record: both still read.
    from opendnc.server.core.state import State, from_stored

    stored = [
        ("active", "ACTIVE"),
        ("none", ""),
        ("running", "ACTIVE"),
        ("no_record", ""),
        ("ready", "READY"),
    ]
    assert [from_stored(w, e) for w, e in stored] == [
        State.RUNNING,
        State.NO_RECORD,
        State.RUNNING,
        State.NO_RECORD,
        State.READY,
    ]
    assert from_stored("garbage", "") is State.UNKNOWN
