"""Property tests: modal tracker, DNC stream parser and the XON/XOFF streamer."""

from __future__ import annotations

import functools

from hypothesis import given
from hypothesis import strategies as st

from opendnc.errors import RemoteProtocolError
from opendnc.haas.dnc import DncConfig, DncStreamer
from opendnc.haas.modal import ModalState, restart_preamble, scan, track
from opendnc.sim.haas.dnc_link import DncLimits, DncReceiver
from opendnc.xmodem.haas import Eob

words = st.sampled_from(
    ["G", "M", "T", "S", "F", "H", "P", "X", "#", "O", "N", "(", ")", ";", "/", "[", "=", " "]
)
numbers = st.sampled_from(
    ["0", "1", "3", "6", "17", "20", "21", "43", "54", "91", "154", ".5", "-"]
)
gcode_lines = st.lists(st.one_of(words, numbers), max_size=12).map("".join)
any_text = st.text(max_size=60)


@given(st.lists(st.one_of(gcode_lines, any_text), max_size=30), st.integers(1, 10_000))
def test_tracker_is_total_and_a_fold(lines: list[str], at: int) -> None:
    state = scan(lines)
    assert state == functools.reduce(track, lines, ModalState())
    plan = restart_preamble(state, at)
    assert plan.preamble[0] == "%"
    assert all(isinstance(b, str) and "\n" not in b and "\r" not in b for b in plan.preamble)
    assert plan.line == at


@given(st.lists(gcode_lines, max_size=30))
def test_tracker_ignores_comments(lines: list[str]) -> None:
    commented = [f"({line.replace(')', '')})" for line in lines]
    assert scan(commented) == ModalState()


def _feed_all(rx: DncReceiver, chunks: list[bytes]) -> list[str] | str:
    out: list[str] = []
    try:
        for chunk in chunks:
            out += rx.receive_data(chunk)
    except RemoteProtocolError:
        return "error"
    return out


@given(st.binary(max_size=300), st.lists(st.integers(1, 50), max_size=20))
def test_receiver_any_bytes_any_split(data: bytes, cuts: list[int]) -> None:
    limits = DncLimits(max_block=64)
    whole = _feed_all(DncReceiver(limits), [data])
    chunks, rest = [], data
    for cut in cuts:
        chunks.append(rest[:cut])
        rest = rest[cut:]
    chunks.append(rest)
    split = _feed_all(DncReceiver(limits), chunks)
    assert whole == split
    if whole != "error":
        assert all(line and line == line.strip() for line in whole)


blocks = st.lists(
    st.text(alphabet="GXYZMF0123456789. #=[]", min_size=1, max_size=30).filter(
        lambda s: s.strip() and s.strip() != "%"
    ),
    max_size=20,
)


@given(blocks, st.sampled_from(list(Eob)))
def test_receiver_round_trip_any_eob(lines: list[str], eob: Eob) -> None:
    wire = eob.wire.join([b"%", *(line.encode() for line in lines), b"%"]) + eob.wire
    got = DncReceiver().receive_data(wire)
    assert got == [line.strip() for line in lines] + ["%"]


@given(
    st.binary(min_size=1, max_size=200),
    st.lists(st.sampled_from([b"\x13", b"\x11", b"x", b""]), max_size=40),
    st.integers(1, 16),
)
def test_streamer_never_writes_while_paused(data: bytes, inputs: list[bytes], chunk: int) -> None:
    streamer = DncStreamer(DncConfig(chunk=chunk))
    streamer.queue(data)
    out = bytearray()
    for incoming in inputs:
        streamer.receive_data(incoming)
        piece = streamer.data_to_send()
        if streamer.paused:
            assert piece == b""
        assert len(piece) <= chunk
        out += piece
    streamer.receive_data(b"\x11")
    while piece := streamer.data_to_send():
        out += piece
    assert bytes(out) == data
    assert streamer.sent == len(data)
