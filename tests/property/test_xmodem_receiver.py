"""Hypothesis: any byte stream into the XModem engines yields ACK/NAK/CAN or a typed error.

Near-valid input (real blocks, sometimes mutated, mixed with control bytes and junk, fed in
random slices with timer expiries in between) must never crash an engine, and everything the
receiver releases as file data must come from blocks that really were on the wire.
"""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from opendnc.errors import DncError
from opendnc.xmodem.events import Completed, DataReceived
from opendnc.xmodem.framing import ACK, CAN, CRC_REQUEST, EOT, NAK, Mode, encode_block
from opendnc.xmodem.receiver import XmodemReceiver
from opendnc.xmodem.sender import XmodemSender

ANSWERS = {ACK, NAK, CAN, CRC_REQUEST}


@st.composite
def near_valid_stream(draw: st.DrawFn) -> tuple[list[bytes], set[bytes]]:
    """Pieces of wire data and the set of 128/1024-byte payloads that were really encoded."""
    crc = draw(st.booleans())
    pieces: list[bytes] = []
    payloads: set[bytes] = set()
    for _ in range(draw(st.integers(0, 8))):
        kind = draw(st.sampled_from(["block", "block", "block", "control", "junk"]))
        if kind == "block":
            large = crc and draw(st.booleans())
            data = draw(st.binary(max_size=1024 if large else 128))
            seq = draw(st.one_of(st.integers(0, 3), st.integers(0, 255)))
            raw = bytearray(encode_block(seq, data, crc=crc, large=large))
            payloads.add(bytes(raw[3 : 3 + (1024 if large else 128)]))
            if draw(st.booleans()):
                where = draw(st.integers(0, len(raw) - 1))
                raw[where] ^= draw(st.integers(1, 255))
            if draw(st.integers(0, 4)) == 0:
                raw = raw[: draw(st.integers(0, len(raw)))]
            pieces.append(bytes(raw))
        elif kind == "control":
            pieces.append(
                bytes(draw(st.lists(st.sampled_from([EOT, CAN]), min_size=1, max_size=3)))
            )
        else:
            pieces.append(draw(st.binary(min_size=1, max_size=40)))
    return pieces, payloads


@settings(max_examples=300, deadline=None)
@given(
    stream=near_valid_stream(),
    mode=st.sampled_from(list(Mode)),
    cuts=st.lists(st.integers(1, 200), max_size=10),
    ticks=st.lists(st.booleans(), max_size=40),
)
def test_receiver_never_crashes(
    stream: tuple[list[bytes], set[bytes]], mode: Mode, cuts: list[int], ticks: list[bool]
) -> None:
    pieces, payloads = stream
    receiver = XmodemReceiver(mode)
    wire = b"".join(pieces)
    sent = bytearray(receiver.data_to_send())
    released: list[bytes] = []
    position, step = 0, 0
    while position < len(wire) and not receiver.finished:
        size = cuts[step % len(cuts)] if cuts else len(wire)
        receiver.receive_data(wire[position : position + size])
        position += size
        if ticks and ticks[step % len(ticks)]:
            receiver.timed_out()
        step += 1
        sent += receiver.data_to_send()
    for _ in range(40):  # let every timer run out: the engine must end up finished
        if receiver.finished:
            break
        receiver.timed_out()
        sent += receiver.data_to_send()
    while (event := receiver.next_event()) is not None:
        if isinstance(event, DataReceived):
            released.append(event.data)
    assert set(sent) <= ANSWERS
    assert receiver.finished
    if receiver.error is not None:
        assert isinstance(receiver.error, DncError)
    else:
        assert isinstance(receiver.result, Completed)
    # every released piece is a payload that was really encoded (mutations never pass);
    # the last piece may have lost its SUB padding
    stripped = {p.rstrip(b"\x1a") for p in payloads}
    for piece in released:
        assert piece in payloads or piece in stripped


@settings(max_examples=300, deadline=None)
@given(
    answers=st.lists(st.binary(min_size=1, max_size=6), max_size=30),
    ticks=st.lists(st.booleans(), max_size=30),
    mode=st.sampled_from(list(Mode)),
    size=st.integers(1, 3000),
)
def test_sender_never_crashes(
    answers: list[bytes], ticks: list[bool], mode: Mode, size: int
) -> None:
    sender = XmodemSender(bytes(size), mode)
    for i, answer in enumerate(answers):
        sender.receive_data(answer)
        if ticks and ticks[i % len(ticks)]:
            sender.timed_out()
        sender.data_to_send()
    for _ in range(200):
        if sender.finished:
            break
        sender.timed_out()
    while sender.next_event() is not None:
        pass
    assert sender.finished
    assert sender.error is None or isinstance(sender.error, DncError)
    assert sender.sent <= sender.total
