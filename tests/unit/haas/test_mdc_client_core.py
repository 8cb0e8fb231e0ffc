"""The sans-IO MDC client core, stepped by hand: what both clients do, decided in one place."""

from __future__ import annotations

from collections.abc import Callable

import pytest

from opendnc.errors import PeerClosed, TransportTimeout
from opendnc.haas import mdc
from opendnc.haas.mdc_client import (
    WAITING,
    Io,
    IoStep,
    MdcClientCore,
    Receive,
    Send,
    macro_get_op,
    query_op,
)


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def drive(io: Io[object], answer: Callable[[IoStep], bytes | None]) -> object:
    """Step ``io`` to its end, answering each step with ``answer(step)`` (a scripted driver)."""
    step = next(io)
    while True:
        try:
            step = io.send(answer(step))
        except StopIteration as done:
            return done.value


def test_first_request_is_sent_twice_then_times_out() -> None:
    clock = Clock()
    core = MdcClientCore(timeout=2.0, clock=clock)
    sent: list[bytes] = []

    def silent(step: IoStep) -> bytes | None:
        if isinstance(step, Send):
            sent.append(step.data)
            return b""
        if step != Receive(WAITING):
            assert 0 < step.timeout <= 2.0
            clock.now += step.timeout  # the whole wait passes in silence
        return None

    with pytest.raises(TransportTimeout, match="asked twice"):
        drive(core.run(query_op(100)), silent)
    assert sent == [b"?Q100\r\n", b"?Q100\r\n"]


def test_later_requests_are_sent_once() -> None:
    core = MdcClientCore(timeout=1.0, clock=Clock())
    io = core.run(query_op(102))
    assert next(io) == Receive(WAITING)
    assert io.send(None) == Send(b"?Q102\r\n", 1.0)
    assert isinstance(io.send(b""), Receive)
    with pytest.raises(StopIteration) as done:
        io.send(b">MODEL, VF-2\r\n")
    assert done.value.value == mdc.TextValue("MODEL", "VF-2")
    io = core.run(query_op(100))
    assert next(io) == Receive(WAITING)
    assert io.send(None) == Send(b"?Q100\r\n", 1.0)
    assert isinstance(io.send(b""), Receive)
    with pytest.raises(TransportTimeout) as timed_out:
        io.send(None)
    assert "asked twice" not in str(timed_out.value)


def test_a_control_that_stops_reading_is_a_timeout() -> None:
    core = MdcClientCore(timeout=1.5, clock=Clock())
    io = core.run(macro_get_op(100))
    assert next(io) == Receive(WAITING)
    assert isinstance(io.send(None), Send)
    with pytest.raises(TransportTimeout, match="stopped reading"):
        io.send(None)  # the driver could not write the request in time


def test_other_clients_replies_do_not_extend_the_deadline() -> None:
    clock = Clock()
    core = MdcClientCore(timeout=1.0, clock=clock)
    waits = 0

    def chatty(step: IoStep) -> bytes | None:
        nonlocal waits
        if isinstance(step, Send):
            return b""
        if step == Receive(WAITING):
            return None
        waits += 1
        clock.now += 0.1
        return b">SERIAL NUMBER, 1\r\n"  # someone else's reply, again and again

    with pytest.raises(TransportTimeout):
        drive(core.run(query_op(102)), chatty)
    assert 10 <= waits <= 22  # two attempts of about ten 0.1 s reads each, then no more


def test_waiting_bytes_are_taken_within_a_budget() -> None:
    core = MdcClientCore(timeout=1.0, clock=Clock())
    io = core.run(query_op(102))
    step = next(io)
    reads = 0
    while step == Receive(WAITING):
        reads += 1
        assert reads < 100, "a flooding peer holds the request back"
        step = io.send(b">SERIAL NUMBER, 1\r\n" * 200)
    assert isinstance(step, Send)


def test_peer_closed_while_waiting() -> None:
    core = MdcClientCore(timeout=1.0, clock=Clock())
    io = core.run(query_op(102))
    next(io)
    io.send(None)
    io.send(b"")
    with pytest.raises(PeerClosed):
        io.send(b"")
