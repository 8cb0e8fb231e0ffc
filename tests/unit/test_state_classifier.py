"""The one state classifier: a transfer is not running, silence is unknown, errors win."""

from __future__ import annotations

from datetime import UTC, datetime

import pytest

from opendnc.server.core.state import State, classify, classify_words
from opendnc.server.core.status import MachineStatus

NOW = datetime(2026, 11, 27, tzinfo=UTC)


@pytest.mark.parametrize(
    ("execution", "expected"),
    [
        ("ACTIVE", State.RUNNING),
        ("READY", State.READY),
        ("PROGRAM_COMPLETED", State.READY),
        ("FEED_HOLD", State.STOPPED),
        ("INTERRUPTED", State.STOPPED),
        ("STOPPED", State.STOPPED),
        ("UNAVAILABLE", State.UNKNOWN),
        ("", State.UNKNOWN),
    ],
)
def test_execution_words(execution: str, expected: State) -> None:
    status = MachineStatus(at=NOW, available=True, execution=execution)
    assert classify(status, online=True) is expected


def test_errors_are_an_alarm_whatever_runs() -> None:
    status = MachineStatus(at=NOW, available=True, execution="ACTIVE", errors=("1001 SERVO",))
    assert classify(status, online=True) is State.ALARM


def test_offline_wins_over_everything() -> None:
    status = MachineStatus(at=NOW, available=True, execution="ACTIVE", errors=("x",))
    assert classify(status, online=False) is State.OFFLINE
    assert classify(None, online=False) is State.OFFLINE
    assert classify_words(online=False, execution="ACTIVE", errors=False) is State.OFFLINE


def test_a_silent_reachable_control_is_unknown_not_idle() -> None:
    assert classify(None, online=True) is State.UNKNOWN
    assert classify(MachineStatus(at=NOW, available=True), online=True) is State.UNKNOWN
