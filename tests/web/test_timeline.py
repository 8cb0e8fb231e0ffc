"""The status timeline's bookkeeping: changes only, placed on a strip over a time window."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import pytest

from tests.peers import require_module

require_module("jinja2")

from opendnc.server.web.timeline import Timeline  # noqa: E402

T0 = datetime(2026, 1, 5, 8, 0, tzinfo=UTC)


def _machine(execution: str, mode: str = "AUTOMATIC", online: bool = True) -> dict[str, object]:
    return {"online": online, "status": {"execution": execution, "mode": mode, "errors": []}}


def test_only_changes_are_kept_and_segments_fill_the_window() -> None:
    tl = Timeline()
    tl.note("m", _machine("READY"), T0)
    tl.note("m", _machine("READY"), T0 + timedelta(minutes=5))  # no change: not kept
    tl.note("m", _machine("ACTIVE"), T0 + timedelta(hours=1))
    tl.note("m", _machine("", online=False), T0 + timedelta(hours=3))
    assert len(tl.changes["m"]) == 3
    segments = tl.segments("m", hours=4, width=400, now=T0 + timedelta(hours=4))
    assert [(s.x, s.width, s.state) for s in segments] == [
        (0.0, 100.0, "ready"),
        (100.0, 200.0, "active"),
        (300.0, 100.0, "offline"),
    ]
    assert segments[1].label == "active, automatic"


def test_what_began_before_the_window_is_cut_at_its_start() -> None:
    tl = Timeline()
    tl.note("m", _machine("STOPPED"), T0)
    segments = tl.segments("m", hours=1, width=100, now=T0 + timedelta(hours=3))
    assert [(s.x, s.width, s.state) for s in segments] == [(0.0, 100.0, "stopped")]
    assert tl.segments("other", now=T0) == []


@pytest.mark.parametrize(
    ("machine", "state"),
    [
        ({"online": True, "status": {"execution": "READY", "errors": ["E1"]}}, "alarm"),
        ({"online": True, "status": {"execution": "INTERRUPTED"}}, "stopped"),
        ({"online": False, "status": None}, "offline"),
    ],
)
def test_states(machine: dict[str, object], state: str) -> None:
    tl = Timeline()
    tl.note("m", machine, T0)
    assert tl.segments("m", hours=1, now=T0 + timedelta(minutes=1))[0].state == state
