"""Where a stopped drip-feed is, exactly, and what its continuation sends
(docs/server.md#a-fenced-drip-feed).

The expected bytes are written out by hand from the program text and the wire rules (an added
``%`` line before and after, the EOB after every line, NULs of leader and trailer): never read
back from the engine.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from opendnc.errors import InputError, PeerClosed, TransportError
from opendnc.haas.dnc import stream_program
from opendnc.haas.dnc_engine import (
    XOFF,
    DncConfig,
    DncRun,
    Drain,
    FeedPosition,
    Finish,
    ProgramFeed,
    Send,
    Wait,
)

PROGRAM = b"O1000\nG0 X1.\nG1 X2. Y3. F10.\n\nM30\n"
# the whole feed as the control receives it, with a two-NUL leader and trailer
WIRE = b"%\nO1000\nG0 X1.\nG1 X2. Y3. F10.\nM30\n%\n"
LEADER = b"\0\0"
TRAILER = b"\0\0"
CONFIG = DncConfig(chunk=4, leader=LEADER, trailer=TRAILER)


@pytest.fixture
def program(tmp_path: Path) -> Path:
    path = tmp_path / "O1000.nc"
    path.write_bytes(PROGRAM)
    return path


def _open(feeds: list[ProgramFeed], path: Path, **options: int) -> ProgramFeed:
    feed = ProgramFeed(path, **options)  # type: ignore[arg-type]
    feeds.append(feed)
    return feed


def _feed_until(run: DncRun, nbytes: int) -> bytes:
    """Write chunks until at least ``nbytes`` went out, then the control says XOFF."""
    out = b""
    while len(out) < nbytes:
        step = run.next_step()
        assert isinstance(step, Send), step
        out += step.data
    run.incoming(bytes([XOFF]))
    assert isinstance(run.next_step(), Wait)  # held: nothing more is written
    return out


def _rest(run: DncRun) -> bytes:
    out = b""
    while True:
        step = run.next_step()
        if isinstance(step, Send):
            out += step.data
        elif isinstance(step, Finish):
            return out
        elif isinstance(step, Wait | Drain):
            run.link_closed()  # the control's linger is not waited for here


def _continuation(path: Path, position: FeedPosition, config: DncConfig = CONFIG) -> bytes:
    feed = ProgramFeed(path, eob=config.eob, resume_at=position.offset)
    try:
        return _rest(DncRun(feed, config, skip=position.written))
    finally:
        feed.close()


@pytest.fixture
def feeds() -> Iterator[list[ProgramFeed]]:
    """The feeds a test opens, closed after it."""
    opened: list[ProgramFeed] = []
    yield opened
    for feed in opened:
        feed.close()


def test_an_xoff_mid_line_gives_the_line_and_the_bytes_the_control_has(
    program: Path, feeds: list[ProgramFeed]
) -> None:
    run = DncRun(_open(feeds, program), CONFIG)
    # leader 2 + "%\n" 2 + "O1000\n" 6 + "G0 X1.\n" 7 = 17; chunks of 4 stop at 20, three bytes
    # into "G1 X2. Y3. F10.\n"
    sent = _feed_until(run, 18)
    assert sent == LEADER + b"%\nO1000\nG0 X1.\nG1 "
    position = run.position()
    assert position == FeedPosition(offset=len(b"O1000\nG0 X1.\n"), written=b"G1 ")
    rest = _continuation(program, position)
    # the rest of the line and the lines after: no leader, no opening %, nothing twice
    assert rest == b"X2. Y3. F10.\nM30\n%\n" + TRAILER
    assert sent + rest == LEADER + WIRE + TRAILER


def test_a_stop_at_a_line_end_continues_with_the_next_line(
    program: Path, feeds: list[ProgramFeed]
) -> None:
    run = DncRun(_open(feeds, program), DncConfig(chunk=1, leader=LEADER))
    sent = _feed_until(run, len(LEADER + b"%\nO1000\n"))
    assert sent.endswith(b"O1000\n")
    position = run.position()
    assert position == FeedPosition(offset=len(b"O1000\n"))
    assert _continuation(program, position, DncConfig(leader=LEADER)) == (
        b"G0 X1.\nG1 X2. Y3. F10.\nM30\n%\n"
    )


def test_inside_the_closing_percent_only_its_rest_goes(
    program: Path, feeds: list[ProgramFeed]
) -> None:
    run = DncRun(_open(feeds, program), DncConfig(chunk=1))
    _feed_until(run, len(WIRE) - 1)  # "%" of the added closing line out, its LF not
    position = run.position()
    assert position == FeedPosition(offset=len(PROGRAM), written=b"%")
    assert _continuation(program, position, DncConfig()) == b"\n"


def test_a_stop_inside_the_leader_or_the_opening_has_no_position(
    program: Path, feeds: list[ProgramFeed]
) -> None:
    run = DncRun(_open(feeds, program), DncConfig(chunk=1, leader=LEADER))
    _feed_until(run, 1)
    assert run.position() is None
    run = DncRun(_open(feeds, program), DncConfig(chunk=1, leader=LEADER))
    _feed_until(run, len(LEADER) + 1)  # half of the added "%" line
    assert run.position() is None


def test_a_stop_inside_a_restart_preamble_has_no_position(
    program: Path, feeds: list[ProgramFeed]
) -> None:
    run = DncRun(_open(feeds, program, from_line=3), DncConfig(chunk=1))
    _feed_until(run, 3)  # into the preamble that stands for lines 1 and 2
    assert run.position() is None


def test_a_file_with_cr_only_line_ends_has_no_position(
    tmp_path: Path, feeds: list[ProgramFeed]
) -> None:
    path = tmp_path / "O1001.nc"
    path.write_bytes(b"O1001\rG0 X1.\rG1 X2.\rM30\r")
    run = DncRun(_open(feeds, path), DncConfig(chunk=1))
    _feed_until(run, len(b"%\nO1001\nG0 X1.\n"))
    assert run.position() is None


def test_a_stop_inside_a_write_has_no_position(program: Path, feeds: list[ProgramFeed]) -> None:
    run = DncRun(_open(feeds, program), DncConfig(chunk=1))
    _feed_until(run, 10)
    run.writing = True  # what a driver says while a write is under way
    assert run.position() is None


def test_a_continuation_refuses_bytes_that_are_not_the_programs(program: Path) -> None:
    wrong = FeedPosition(offset=len(b"O1000\n"), written=b"G1")
    with pytest.raises(InputError):
        _continuation(program, wrong)
    with pytest.raises(InputError):  # not the start of a line
        ProgramFeed(program, resume_at=3)


class HeldPort:
    """A port whose control says XOFF once ``hold_after`` bytes were written; then the link is
    closed under the waiting feed (what a fence does), or the write itself fails."""

    def __init__(self, hold_after: int, fail_write: bool = False) -> None:
        self.hold_after = hold_after
        self.fail_write = fail_write
        self.written = b""
        self.held = False

    def read_nowait(self, max_bytes: int) -> bytes:
        if len(self.written) >= self.hold_after and not self.held and not self.fail_write:
            self.held = True
            return bytes([XOFF])
        return b""

    def read(self, max_bytes: int) -> bytes:
        if self.held:
            raise PeerClosed("closed under the feed")
        return b""

    def write(self, data: bytes) -> int:
        if self.fail_write and len(self.written) >= self.hold_after:
            raise TransportError("closed under a write")
        self.written += data
        return len(data)

    def drain(self) -> None:
        """Nothing buffered."""

    def set_timeout(self, seconds: float | None) -> None:
        """Reads never wait here."""


HELD_AT = b"%\nO1000\nG0 X1.\nG1 "  # what the control has when its XOFF holds the feed


def _stop_held(
    program: Path, port: HeldPort, error: type[Exception], **options: Any
) -> FeedPosition | None:
    """Feed ``program`` on ``port`` (held by XOFF after :data:`HELD_AT`) until it stops with
    ``error``; it must have written nothing more and say it stopped inside the third line.
    Returns where it said it stopped."""
    stops: list[FeedPosition | None] = []
    with pytest.raises(error):
        stream_program(
            port,  # type: ignore[arg-type]
            program,
            config=DncConfig(chunk=1),
            safe_mode=False,
            stopped=stops.append,
            **options,
        )
    assert port.written == HELD_AT
    assert stops == [FeedPosition(len(b"O1000\nG0 X1.\n"), b"G1 ")]
    return stops[0]


def test_a_feed_closed_under_its_xoff_says_where_it_stopped(program: Path) -> None:
    port = HeldPort(hold_after=len(HELD_AT))
    stopped = _stop_held(program, port, PeerClosed)
    # the rest from there, through the same entry point, on a port that does not hold
    rest = HeldPort(hold_after=10**9)
    stream_program(
        rest,  # type: ignore[arg-type]
        program,
        config=DncConfig(chunk=1, linger=0),
        safe_mode=False,
        resume=stopped,
    )
    assert port.written + rest.written == WIRE


def test_a_feed_stopped_inside_a_write_says_it_does_not_know(program: Path) -> None:
    port = HeldPort(hold_after=9, fail_write=True)
    stops: list[FeedPosition | None] = []
    with pytest.raises(TransportError):
        stream_program(
            port,  # type: ignore[arg-type]
            program,
            config=DncConfig(chunk=1),
            safe_mode=False,
            stopped=stops.append,
        )
    assert stops == [None]


class Fence(Exception):
    """What a server's fence check raises (the runner's Fenced, here without the runner)."""


class SilentPort(HeldPort):
    """A held port that is never closed: only the feed's own ``waiting`` check can stop it."""

    def __init__(self, hold_after: int) -> None:
        super().__init__(hold_after)
        self.reads = 0

    def read(self, max_bytes: int) -> bytes:
        self.reads += 1
        if self.reads > 100:
            raise AssertionError("the held feed waited on: nothing stopped it")
        return b""


def test_a_held_feed_stops_itself_at_the_fence_where_it_stands(program: Path) -> None:
    # A fence need not close the link under a feed held by XOFF: asked before each wait, the
    # check stops it there, with the same exact position a closed link gives.
    port = SilentPort(hold_after=len(HELD_AT))

    def waiting() -> None:
        if port.held:
            raise Fence("the lease could expire")

    _stop_held(program, port, Fence, waiting=waiting)
    assert port.reads == 0  # stopped before waiting on the port at all
