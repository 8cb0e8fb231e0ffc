"""The virtual Haas's side of a drip-feed: blocks out of bytes, XON/XOFF decisions."""

from __future__ import annotations

import pytest

from opendnc.errors import InputError, RemoteProtocolError
from opendnc.sim.haas.dnc_link import XOFF, XON, DncLimits, DncReceiver, Framing


def test_leader_ignored_until_percent_and_closing_percent_ends() -> None:
    rx = DncReceiver()
    assert rx.receive_data(b"\x00\x00 junk\n") == []
    assert rx.framing is Framing.LEADER
    assert rx.receive_data(b"%\nO00001\nG01 X1.\n%\nafter\n") == ["O00001", "G01 X1.", "%"]
    assert rx.framing is Framing.ENDED
    assert rx.receive_data(b"more\n") == []


@pytest.mark.parametrize("eob", [b"\n", b"\r", b"\r\n", b"\r\r", b"\n\n"])
def test_every_eob_pattern(eob: bytes) -> None:
    rx = DncReceiver()
    wire = eob.join([b"%", b"G00 X1.", b"M30", b"%"]) + eob
    assert rx.receive_data(wire) == ["G00 X1.", "M30", "%"]


def test_split_anywhere_and_control_bytes_removed() -> None:
    rx = DncReceiver()
    out: list[str] = []
    for byte in b"%\nG0\x111 X\x131.\nM3\x120\n%\n":
        out += rx.receive_data(bytes((byte,)))
    assert out == ["G01 X1.", "M30", "%"]


def test_flow_decisions() -> None:
    rx = DncReceiver(DncLimits(buffer_blocks=4, resume_blocks=1, overrun_blocks=2))
    rx.receive_data(b"%\n")
    assert rx.flow(3) == b""
    assert rx.flow(4) == XOFF
    assert rx.flow(5) == b""  # already stopped
    assert rx.flow(2) == b""
    assert rx.flow(1) == XON
    assert (rx.xoffs, rx.xons) == (1, 1)
    assert not rx.overrun(6)
    assert rx.overrun(7)


def test_closing_percent_releases_xoff() -> None:
    rx = DncReceiver(DncLimits(buffer_blocks=2, resume_blocks=0))
    rx.receive_data(b"%\n")
    assert rx.flow(2) == XOFF
    rx.receive_data(b"%\n")
    assert rx.flow(2) == XON


def test_limits() -> None:
    rx = DncReceiver(DncLimits(max_block=8))
    with pytest.raises(RemoteProtocolError, match="longer than 8"):
        rx.receive_data(b"%\n0123456789")
    with pytest.raises(InputError):
        DncLimits(buffer_blocks=4, resume_blocks=4)
