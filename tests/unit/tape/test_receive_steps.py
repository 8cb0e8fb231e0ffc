"""The punch receive's waits (``receive_steps``), which the blocking and the asyncio drivers
share: driven here by a clock the test moves, with no port and no sleeping."""

from __future__ import annotations

import pytest

from opendnc.errors import TransferError, TransportTimeout
from opendnc.tape.codes import Code, Codec
from opendnc.tape.profiles import get_profile
from opendnc.tape.reader import End
from opendnc.tape.session import PunchReceiver, Received, ReceiveSteps, receive_steps


class Clock:
    """A clock that moves only when the test says."""

    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def _iso(text: str) -> bytes:
    return Codec(Code.ISO, parity=True).encode_text(text, 0)


def _finish(steps: ReceiveSteps, data: bytes | None) -> Received:
    with pytest.raises(StopIteration) as done:
        steps.send(data)
    record: Received = done.value.value
    return record


def test_the_start_timeout_counts_on_the_clock_not_in_waits() -> None:
    clock = Clock()
    steps = receive_steps(PunchReceiver(get_profile("fanuc-0i"), start_timeout=5.0), clock)
    assert next(steps) == pytest.approx(5.0)
    clock.now += 2.0
    assert steps.send(None) == pytest.approx(3.0)  # a short read: the rest of the 5 s
    clock.now += 1.0
    assert steps.send(_iso("\x11")) == pytest.approx(2.0)  # a flow byte starts no punch
    clock.now += 2.0
    with pytest.raises(TransportTimeout, match="no punch from the control within 5 s"):
        steps.send(None)


def test_each_character_rearms_the_quiet_and_the_end_mark_returns_the_record() -> None:
    clock = Clock()
    receiver = PunchReceiver(get_profile("fanuc-0i"), start_timeout=5.0, quiet=1.0)
    steps = receive_steps(receiver, clock)
    next(steps)
    clock.now += 4.0
    assert steps.send(b"\x12" + _iso("%\nO0009\n")) == pytest.approx(1.0)  # quiet, from now
    clock.now += 0.75
    assert steps.send(None) == pytest.approx(0.25)
    assert steps.send(_iso("G01 X1.\n")) == pytest.approx(1.0)
    record = _finish(steps, _iso("%\n"))
    assert (record.text, record.name, record.ended) == (
        "%\nO0009\nG01 X1.\n%\n",
        "O0009.nc",
        End.PERCENT,
    )


def test_no_timer_means_no_limit_and_a_closed_link_loses_the_record() -> None:
    steps = receive_steps(PunchReceiver(get_profile("fanuc-0i")), Clock())
    assert next(steps) is None  # no start timeout: the driver may wait without limit
    assert steps.send(b"\x12" + _iso("%\nO0009\n")) is not None  # started: the quiet runs
    with pytest.raises(TransferError, match="the link closed"):
        steps.send(b"")


def test_quiet_after_the_record_ends_it_when_asked() -> None:
    clock = Clock()
    receiver = PunchReceiver(get_profile("fanuc-0i"), quiet=0.5, quiet_ends=True)
    steps = receive_steps(receiver, clock)
    next(steps)
    steps.send(b"\x12" + _iso("X 1.500\n"))
    clock.now += 0.5
    assert _finish(steps, None).text == "X 1.500\n"
