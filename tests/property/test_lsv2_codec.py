"""Hypothesis properties of the LSV2 framers and codec.

1. Frames encoded back to back and cut at random points come back unchanged (TCP and serial).
2. Random, near-valid and mutated input fed to framer + decoder raises only
   RemoteProtocolError (never another exception, never a hang).
"""

from __future__ import annotations

import contextlib
import struct

from hypothesis import given, settings
from hypothesis import strategies as st

from opendnc.errors import RemoteProtocolError
from opendnc.lsv2.connection import Lsv2Connection, Role
from opendnc.lsv2.framing import (
    Frame,
    SerialControl,
    SerialFramer,
    TelegramFramer,
    encode_serial_frame,
)
from opendnc.lsv2.messages import REGISTRY, decode, encode
from tests.unit.lsv2.samples import SAMPLES

names = st.text(
    alphabet=st.characters(min_codepoint=0x21, max_codepoint=0x7E), min_size=4, max_size=4
)
frames = st.builds(Frame, names, st.binary(max_size=300))
known_names = st.sampled_from(sorted(REGISTRY))


def _cut(data: bytes, cuts: list[int]) -> list[bytes]:
    points = sorted({c % (len(data) + 1) for c in cuts})
    pieces, last = [], 0
    for p in [*points, len(data)]:
        pieces.append(data[last:p])
        last = p
    return pieces


@given(st.lists(frames, max_size=8), st.lists(st.integers(0, 10_000), max_size=12))
def test_tcp_frames_survive_any_split(items: list[Frame], cuts: list[int]) -> None:
    wire = b"".join(TelegramFramer.encode(f) for f in items)
    framer = TelegramFramer()
    out: list[Frame] = []
    for piece in _cut(wire, cuts):
        framer.feed(piece)
        while (f := framer.next_frame()) is not None:
            out.append(f)
    assert out == items


@given(st.lists(frames, max_size=6), st.lists(st.integers(0, 10_000), max_size=12))
def test_serial_frames_survive_any_split(items: list[Frame], cuts: list[int]) -> None:
    wire = b"".join(encode_serial_frame(f) + b"\x10\x31" for f in items)
    framer = SerialFramer()
    out: list[Frame | SerialControl] = []
    for piece in _cut(wire, cuts):
        framer.feed(piece)
        while (f := framer.next_frame()) is not None:
            out.append(f)
    expected: list[Frame | SerialControl] = []
    for f in items:
        expected += [f, SerialControl.RECEIVED]
    assert out == expected


@given(st.sampled_from(SAMPLES), st.lists(st.integers(0, 10_000), max_size=6))
def test_messages_survive_engine_and_split(message: object, cuts: list[int]) -> None:
    server = Lsv2Connection(Role.SERVER)
    server.buffer_size = 1 << 20
    wire = TelegramFramer.encode(encode(message))  # type: ignore[arg-type]
    got = []
    for piece in _cut(wire, cuts):
        if not piece:
            continue  # b"" would mean end of stream
        server.receive_data(piece)
        while (m := server.next_event()) is not None:
            got.append(m)
    assert got == [message]


@st.composite
def near_valid_tcp(draw: st.DrawFn) -> bytes:
    name = draw(st.one_of(known_names, names)).encode("ascii")
    sample = draw(st.sampled_from(SAMPLES))
    body = draw(st.one_of(st.binary(max_size=80), st.just(encode(sample).payload)))
    length = draw(st.one_of(st.just(len(body)), st.integers(0, 2**32 - 1)))
    wire = bytearray(struct.pack(">I", length) + name + body)
    for _ in range(draw(st.integers(0, 3))):
        wire[draw(st.integers(0, len(wire) - 1))] ^= draw(st.integers(1, 255))
    if draw(st.booleans()):
        del wire[draw(st.integers(0, len(wire) - 1)) :]
    return bytes(wire)


def _drain_tcp(chunks: list[bytes]) -> None:
    framer = TelegramFramer(max_payload=4096)
    for chunk in chunks:
        framer.feed(chunk)
        while True:
            frame = framer.next_frame()
            if frame is None:
                break
            decode(frame)


@settings(max_examples=400)
@given(st.lists(st.one_of(near_valid_tcp(), st.binary(max_size=60)), max_size=4))
def test_tcp_fuzz_only_remote_protocol_errors(chunks: list[bytes]) -> None:
    with contextlib.suppress(RemoteProtocolError):
        _drain_tcp(chunks)


@settings(max_examples=300)
@given(known_names, st.binary(max_size=200))
def test_decode_any_payload_only_remote_protocol_errors(name: str, payload: bytes) -> None:
    with contextlib.suppress(RemoteProtocolError):
        decode(Frame(name, payload))


@st.composite
def near_valid_serial(draw: st.DrawFn) -> bytes:
    sample = draw(st.sampled_from(SAMPLES))
    wire = bytearray(
        draw(st.sampled_from([b"", b"\x05", b"\x10\x30", b"\x04"]))
        + encode_serial_frame(encode(sample))
        + draw(st.sampled_from([b"", b"\x10\x31", b"\x15"]))
    )
    for _ in range(draw(st.integers(0, 3))):
        wire[draw(st.integers(0, len(wire) - 1))] ^= draw(st.integers(1, 255))
    return bytes(wire)


@settings(max_examples=400)
@given(st.lists(st.one_of(near_valid_serial(), st.binary(max_size=60)), max_size=4))
def test_serial_fuzz_only_remote_protocol_errors(chunks: list[bytes]) -> None:
    framer = SerialFramer(max_body=4096)
    for chunk in chunks:
        framer.feed(chunk)
        # Keep going after errors like a link layer would; every call consumes bytes.
        for _ in range(len(chunk) + 2):
            try:
                item = framer.next_frame()
            except RemoteProtocolError:
                continue
            if item is None:
                break
            if isinstance(item, Frame):
                with contextlib.suppress(RemoteProtocolError):
                    decode(item)


@given(st.binary(max_size=5000))
def test_bcc_equals_bytewise_xor(body: bytes) -> None:
    from functools import reduce
    from operator import xor

    from opendnc.lsv2.framing import bcc

    assert bcc(body) == reduce(xor, body, 0x03)
