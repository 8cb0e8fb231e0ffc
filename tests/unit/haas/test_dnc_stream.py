"""The drip-feed core: XON/XOFF flow control, the program feed from disk, the driver's checks."""

from __future__ import annotations

from pathlib import Path

import pytest

from opendnc.errors import InputError, SafetyLockError, TransportTimeout
from opendnc.haas.dnc import (
    DncConfig,
    DncStreamer,
    Flow,
    Paused,
    ProgramFeed,
    Resumed,
    stream_program,
)
from opendnc.xmodem.haas import Eob


def test_chunks_and_pause_within_one_chunk() -> None:
    streamer = DncStreamer(DncConfig(chunk=4))
    streamer.queue(b"G01 X1.\nG01 X2.\n")
    assert streamer.data_to_send() == b"G01 "
    streamer.receive_data(b"\x13")
    assert streamer.paused
    assert streamer.data_to_send() == b""
    assert streamer.next_event() == Paused(4)
    assert streamer.timer is not None
    assert streamer.timer.seconds == 120.0
    streamer.receive_data(b"\x15junk\x11")  # other bytes (a NAK, DPRNT text) are only counted
    assert streamer.next_event() == Resumed(4)
    assert streamer.other == 5
    assert streamer.timer is None
    assert streamer.data_to_send() == b"X1.\n"
    assert streamer.sent == 8
    assert streamer.pending == 8


def test_last_flow_byte_wins() -> None:
    streamer = DncStreamer()
    streamer.queue(b"abc")
    streamer.receive_data(b"\x13\x11\x13")
    assert streamer.paused
    assert (streamer.xoffs, streamer.xons) == (2, 1)
    streamer.receive_data(b"\x13")  # a repeated XOFF does not re-arm the timer
    assert streamer.timer is not None
    assert streamer.timer.serial == 2


def test_xoff_timeout_is_a_typed_error() -> None:
    streamer = DncStreamer(DncConfig(xoff_timeout=5))
    streamer.queue(b"x")
    streamer.receive_data(b"\x13")
    with pytest.raises(TransportTimeout, match="XOFF for more than 5 s"):
        streamer.timed_out()


def test_no_timer_without_timeout_and_flow_none_ignores_xoff() -> None:
    streamer = DncStreamer(DncConfig(xoff_timeout=0))
    streamer.receive_data(b"\x13")
    assert streamer.paused
    assert streamer.timer is None
    hardware = DncStreamer(DncConfig(flow=Flow.RTSCTS))
    hardware.queue(b"abc")
    hardware.receive_data(b"\x13")
    assert not hardware.paused
    assert hardware.data_to_send() == b"abc"
    with pytest.raises(InputError):
        DncStreamer(DncConfig(chunk=0))


def test_wait_for_the_first_xon() -> None:
    streamer = DncStreamer(DncConfig(wait_for_xon=True, xoff_timeout=2))
    streamer.queue(b"%\n")
    assert streamer.data_to_send() == b""
    with pytest.raises(TransportTimeout, match="no XON from the control within 2 s"):
        streamer.timed_out()
    streamer.receive_data(b"\x11")
    assert streamer.data_to_send() == b"%\n"


def _feed(path: Path, **kwargs: object) -> list[bytes]:
    feed = ProgramFeed(path, **kwargs)  # type: ignore[arg-type]
    try:
        return list(feed)
    finally:
        feed.close()


def test_feed_adds_missing_percent_and_skips_blank_lines(tmp_path: Path) -> None:
    path = tmp_path / "p.nc"
    path.write_bytes(b"O00010\r\n\r\nG01 X1.\r\nM30\r\n")
    assert _feed(path) == [b"%\n", b"O00010\n", b"G01 X1.\n", b"M30\n", b"%\n"]
    assert _feed(path, eob=Eob.CRLF)[0] == b"%\r\n"


def test_feed_keeps_existing_delimiters(tmp_path: Path) -> None:
    path = tmp_path / "p.nc"
    path.write_bytes(b"%\nO00010\nM30\n%\n")
    feed = ProgramFeed(path)
    assert list(feed) == [b"%\n", b"O00010\n", b"M30\n", b"%\n"]
    assert feed.position == feed.total == 15
    assert feed.lines == 4
    feed.close()


def test_feed_restart_sends_preamble_then_line_n(tmp_path: Path) -> None:
    path = tmp_path / "p.nc"
    path.write_text("%\nO00020 (R)\nG21\nT2 M06\nG55\nS900 M03\nG01 X1. F100.\nX2.\nX3.\nM30\n%\n")
    feed = ProgramFeed(path, from_line=9, retract=False)
    out = [line.decode().rstrip("\n") for line in feed]
    feed.close()
    assert out == [
        "%",
        "O00020 (R)",
        "(OPENDNC RESTART AT LINE 9)",
        "G21",
        "G00 G17 G40 G80 G90",
        "T2 M06",
        "G55",
        "S900 M03",
        "G01 F100.",
        "X3.",
        "M30",
        "%",
    ]
    assert feed.plan is not None
    assert feed.plan.line == 9


def test_feed_errors(tmp_path: Path) -> None:
    path = tmp_path / "p.nc"
    path.write_text("%\nO1\n%\n")
    with pytest.raises(InputError, match="fewer than 10 lines"):
        _feed(path, from_line=10)
    with pytest.raises(InputError, match="1 or more"):
        ProgramFeed(path, from_line=0)
    with pytest.raises(InputError, match="cannot read"):
        ProgramFeed(tmp_path / "missing.nc")


def test_safe_mode_refuses_before_opening_anything(tmp_path: Path) -> None:
    path = tmp_path / "p.nc"
    path.write_text("%\nO1\n%\n")
    # the message reads as one sentence: "<action> can change machine behaviour and is locked"
    with pytest.raises(
        SafetyLockError, match=r"^drip-feeding p\.nc \(it runs on the machine\) can"
    ):
        stream_program("/dev/does-not-exist", path)
