"""A classic Haas's serial port carries MDC replies, DPRNT lines and XModem/flow-control bytes
together: the MDC reply reader ignores the noise, the DPRNT tap keeps only printed lines."""

from __future__ import annotations

import itertools
import random

from hypothesis import given, settings
from hypothesis import strategies as st

from opendnc.haas.listen import CapturedLine
from opendnc.haas.mdc import LINE_NOISE, ControlType, ReplyFramer, frame_reply
from opendnc.server.kinds.dprnt_tap import DprntTap, TapStream

payloads = st.text(
    alphabet=st.characters(min_codepoint=0x20, max_codepoint=0x7E, exclude_characters=">"),
    min_size=1,
    max_size=40,
).filter(lambda t: t.strip() != "")
printed = st.from_regex(r"[A-Z][A-Z0-9 .\-]{0,30}[A-Z0-9.]", fullmatch=True)


def _sprinkle(data: bytes, rng: random.Random, count: int) -> bytes:
    out = bytearray(data)
    for _ in range(count):
        out.insert(rng.randrange(len(out) + 1), rng.choice(LINE_NOISE))
    return bytes(out)


def _chunks(data: bytes, rng: random.Random) -> list[bytes]:
    cuts = sorted(rng.sample(range(1, len(data)), min(len(data) - 1, 5))) if len(data) > 1 else []
    edges = [0, *cuts, len(data)]
    return [data[a:b] for a, b in itertools.pairwise(edges)]


@settings(max_examples=200)
@given(st.lists(payloads, min_size=1, max_size=5), st.integers(0, 2**32), st.integers(0, 8))
def test_noise_never_changes_a_classic_reply(replies: list[str], seed: int, noise: int) -> None:
    rng = random.Random(seed)
    wire = b"".join(frame_reply(p, ControlType.CLASSIC) for p in replies)
    framer = ReplyFramer()
    for chunk in _chunks(_sprinkle(wire, rng, noise), rng):
        framer.feed(chunk)
    got = []
    while (payload := framer.next_payload()) is not None:
        got.append(payload)
    assert got == [p.strip() for p in replies]


@settings(max_examples=200)
@given(
    st.lists(st.one_of(printed.map(lambda t: ("dprnt", t)), payloads.map(lambda t: ("mdc", t)))),
    st.integers(0, 2**32),
    st.integers(0, 8),
)
def test_the_tap_keeps_printed_lines_and_drops_replies(
    items: list[tuple[str, str]], seed: int, noise: int
) -> None:
    rng = random.Random(seed)
    wire = b"".join(
        frame_reply(text, ControlType.CLASSIC) if kind == "mdc" else text.encode() + b"\r"
        for kind, text in items
    )
    got: list[CapturedLine] = []
    tap = DprntTap(got.append)
    data = _sprinkle(wire, rng, noise)
    for chunk in _chunks(data, rng) if data else []:
        tap.feed(chunk)
    assert [line.text for line in got] == [text for kind, text in items if kind == "dprnt"]


class _Port:
    def __init__(self, chunks: list[bytes]) -> None:
        self.chunks = chunks

    def read(self, max_bytes: int) -> bytes:
        return self.chunks.pop(0)

    def write(self, data: bytes) -> None:
        """Not used."""

    def set_timeout(self, seconds: float | None) -> None:
        """Not used."""

    def close(self) -> None:
        """Not used."""


def test_listening_taps_up_to_the_xmodem_start_only() -> None:
    got: list[CapturedLine] = []
    block = b"\x01\x01\xfe" + b"PASS 9\r".ljust(128, b"\x1a") + b"\x00"
    port = _Port([b"HOLE 1 X 1.5\r\x15", b"HOLE 2 X 3.0\r" + block, b"more\r"])
    stream = TapStream(port, DprntTap(got.append))
    stream.mode = "listen"
    assert stream.read(4096) == b"HOLE 1 X 1.5\r\x15"
    assert stream.read(4096).endswith(block)  # the receiver still gets every byte
    assert stream.mode == "off"
    stream.read(4096)
    assert [(line.text, line.numbers) for line in got] == [
        ("HOLE 1 X 1.5", (1.0, 1.5)),
        ("HOLE 2 X 3.0", (2.0, 3.0)),
    ]
