"""``idle_timeout`` bounds the receiver's whole wait for a sender that went silent mid-transfer."""

from __future__ import annotations

import pytest

from opendnc.errors import TransportTimeout
from opendnc.xmodem.framing import Mode
from opendnc.xmodem.receiver import ReceiverConfig, XmodemReceiver
from opendnc.xmodem.sender import XmodemSender
from tests.unit.xmodem.memwire import Fault, run_wired

DATA = b"G01 X1. F36.\n" * 400


def silent_after(limit: int) -> Fault:
    """A line that goes dead after ``limit`` bytes from the sender (it died, no hang-up)."""
    carried = 0

    def fault(direction: str, data: bytes) -> bytes:
        nonlocal carried
        if direction == "s>r":
            carried += len(data)
            if carried > limit:
                return b""
        return data

    return fault


@pytest.mark.parametrize("idle", [None, 5.0, 25.0])
def test_dead_sender_costs_at_most_idle_timeout(idle: float | None) -> None:
    config = ReceiverConfig(idle_timeout=idle)
    result = run_wired(
        XmodemSender(DATA, Mode.CHECKSUM),
        XmodemReceiver(Mode.CHECKSUM, config),
        fault=silent_after(132 * 3),
    )
    error = result.receiver_error
    assert error is not None
    # the time from the last good block to giving up (the sender's own end does not count)
    if idle is None:
        assert "failed 11 times" in str(error)
        assert result.elapsed > 100
    else:
        assert isinstance(error, TransportTimeout)
        assert f"for {idle:g} s" in str(error)
        assert idle <= result.elapsed < idle + 1


def test_retries_still_count_within_the_budget() -> None:
    """A line that damages every block ends after max_retries, well before the budget."""

    def garble(direction: str, data: bytes) -> bytes:
        if direction == "s>r" and len(data) > 100:
            return data[:50] + bytes([data[50] ^ 1]) + data[51:]
        return data

    result = run_wired(
        XmodemSender(DATA, Mode.CHECKSUM),
        XmodemReceiver(Mode.CHECKSUM, ReceiverConfig(idle_timeout=600.0, max_retries=3)),
        fault=garble,
    )
    assert "failed 4 times" in str(result.receiver_error)
    assert result.elapsed < 60


def test_a_slow_but_alive_sender_is_not_cut() -> None:
    """Each good block restarts the budget: a long transfer may take longer than it."""
    result = run_wired(
        XmodemSender(DATA, Mode.CHECKSUM),
        XmodemReceiver(Mode.CHECKSUM, ReceiverConfig(idle_timeout=2.0)),
        byte_time=0.01,  # 1.3 s per block: the transfer takes about 55 s
    )
    assert result.receiver_error is None
    assert result.received == DATA
    assert result.elapsed > 20
