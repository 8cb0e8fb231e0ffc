"""The drip-feed engine's steps, driven by hand with a fake clock: what every driver carries out."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from opendnc.errors import PeerClosed, TransportTimeout
from opendnc.haas.dnc_engine import (
    POLL,
    DncConfig,
    DncEvent,
    DncRun,
    Drain,
    Finish,
    Paused,
    ProgramFeed,
    Resumed,
    Send,
    Wait,
)


class Clock:
    """A clock the test moves by hand."""

    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


Runner = Callable[[str, DncConfig, Clock], tuple[DncRun, list[DncEvent]]]


@pytest.fixture
def make_run(tmp_path: Path) -> Iterator[Runner]:
    """Build runs over program text; their files are closed after the test."""
    feeds: list[ProgramFeed] = []

    def make(text: str, config: DncConfig, clock: Clock) -> tuple[DncRun, list[DncEvent]]:
        path = tmp_path / f"p{len(feeds)}.nc"
        path.write_text(text)
        feeds.append(ProgramFeed(path))
        events: list[DncEvent] = []
        return DncRun(feeds[-1], config, clock=clock, on_event=events.append), events

    yield make
    for feed in feeds:
        feed.close()


def test_steps_send_wait_on_xoff_resume_and_finish(make_run: Runner) -> None:
    clock = Clock()
    config = DncConfig(chunk=8, xoff_timeout=10, linger=0.5, drain=True)
    run, events = make_run("%\nO1\nG01 X1.\nM30\n%\n", config, clock)
    wire = b"%\nO1\nG01 X1.\nM30\n%\n"
    assert run.next_step() == Send(wire[:8], drain=True)
    run.incoming(b"\x13")  # XOFF between two writes
    clock.now += 2.0
    assert run.next_step() == Wait(POLL)
    clock.now += 3.0
    run.incoming(b"\x11")
    assert events == [Paused(8), Resumed(8)]
    assert run.next_step() == Send(wire[8:16], drain=True)
    assert run.next_step() == Send(wire[16:], drain=True)
    assert run.next_step() == Drain()
    # the link stays open until the control has been quiet for `linger`
    assert run.next_step() == Wait(POLL)
    clock.now += 0.3
    run.incoming(b"\x13\x11")  # still working through its buffer
    clock.now += 0.48
    step = run.next_step()
    assert isinstance(step, Wait)
    assert step.seconds == pytest.approx(0.02)  # quiet for 0.5 s at 0.3 + 0.5
    clock.now += 0.02
    assert run.next_step() == Finish()
    report = run.report()
    assert report.bytes_sent == len(wire)
    assert (report.xoffs, report.xons) == (2, 2)
    assert report.paused_seconds == pytest.approx(5.0)
    assert report.seconds == pytest.approx(5.8)  # 5 s paused, 0.8 s at the end


def test_wait_shrinks_to_the_deadline_then_times_out(make_run: Runner) -> None:
    clock = Clock()
    run, _ = make_run("G01 X1.\n" * 20, DncConfig(chunk=4, xoff_timeout=1.0), clock)
    assert isinstance(run.next_step(), Send)
    run.incoming(b"\x13")
    assert run.next_step() == Wait(POLL)
    clock.now += 0.98
    step = run.next_step()
    assert isinstance(step, Wait)
    assert step.seconds == pytest.approx(0.02)
    clock.now += 0.02
    with pytest.raises(TransportTimeout, match="held XOFF for more than 1 s after 4 bytes"):
        run.next_step()


def test_a_hang_up_ends_the_run_unless_everything_was_sent(make_run: Runner) -> None:
    clock = Clock()
    run, _ = make_run("G01 X1.\n" * 20, DncConfig(chunk=16), clock)
    assert isinstance(run.next_step(), Send)
    run.link_closed()
    with pytest.raises(PeerClosed, match="closed the link after 16 bytes"):
        run.next_step()
    assert run.streamer.sent == 16  # nothing more was handed out for a dead link

    done, _ = make_run("%\nM30\n%\n", DncConfig(chunk=64, linger=10), clock)
    assert isinstance(done.next_step(), Send)
    assert done.next_step() == Drain()
    done.link_closed()  # the control hung up after the last byte: the run is complete
    assert done.next_step() == Finish()


def test_the_end_does_not_wait_longer_than_the_xoff_timeout(make_run: Runner) -> None:
    clock = Clock()
    run, _ = make_run("%\nM30\n%\n", DncConfig(xoff_timeout=2, linger=1), clock)
    assert isinstance(run.next_step(), Send)
    assert run.next_step() == Drain()
    for _ in range(10):  # a control that keeps pausing and resuming
        clock.now += 0.5
        run.incoming(b"\x13\x11")
        if run.next_step() == Finish():
            break
    assert clock.now - 100.0 == pytest.approx(2.0)


def test_without_drain_the_steps_say_so(make_run: Runner) -> None:
    run, _ = make_run("%\nM30\n%\n", DncConfig(drain=False), Clock())
    assert run.next_step() == Send(b"%\nM30\n%\n", drain=False)


def test_leader_and_trailer_surround_the_program(make_run: Runner) -> None:
    clock = Clock()
    config = DncConfig(chunk=64, leader=b"\0" * 5, trailer=b"\0" * 3)
    run, _ = make_run("O1\nM30\n", config, clock)
    sent = b""
    while isinstance(step := run.next_step(), Send):
        sent += step.data
    assert sent == b"\0\0\0\0\0%\nO1\nM30\n%\n\0\0\0"


def test_a_line_delay_holds_each_line_back_after_the_previous_one_left(
    make_run: Runner,
) -> None:
    clock = Clock()
    config = DncConfig(chunk=4, line_delay=0.5, drain=True)
    run, _ = make_run("%\nG01 X1.\nM30\n%\n", config, clock)
    assert run.next_step() == Send(b"%\n", drain=True)
    # The driver drained the line; the delay runs from the next step on.
    step = run.next_step()
    assert isinstance(step, Wait)
    assert step.seconds == pytest.approx(POLL)
    clock.now += 0.49
    step = run.next_step()
    assert isinstance(step, Wait)
    assert step.seconds == pytest.approx(0.01)
    clock.now += 0.01
    # A line goes out in chunks without a pause inside it.
    assert run.next_step() == Send(b"G01 ", drain=True)
    assert run.next_step() == Send(b"X1.\n", drain=True)
    assert isinstance(run.next_step(), Wait)
    clock.now += 0.5
    assert run.next_step() == Send(b"M30\n", drain=True)
