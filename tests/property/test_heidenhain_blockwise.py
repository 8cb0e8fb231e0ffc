"""Hypothesis properties of the blockwise engines: random input never raises, and a line that
loses handshake characters or spoils characters still delivers the exact program or fails
cleanly. A spoilt character arrives as NUL, as from a UART whose parity check (7E1) failed:
the XOR block check alone cannot see two errors in one block that cancel."""

from __future__ import annotations

import random

from hypothesis import given, settings
from hypothesis import strategies as st

from opendnc.heidenhain.blockwise import (
    BlockReceiver,
    BlockSender,
    BlockwiseSettings,
    FileReceived,
    FileRequested,
    TransferFailed,
)

lines = st.lists(
    st.binary(min_size=1, max_size=30).map(
        lambda b: bytes(0x20 + (c % 0x5F) for c in b)  # printable program text
    ),
    max_size=25,
)


@settings(max_examples=200, deadline=None)
@given(data=st.binary(max_size=400), request=st.booleans())
def test_random_bytes_never_raise(data: bytes, request: bool) -> None:
    for engine in (
        BlockReceiver("A.H" if request else None),
        BlockSender(None if request else "A.H", [b"1 L"]),
    ):
        engine.start(0.0)
        for i in range(0, len(data), 7):
            engine.receive_data(data[i : i + 7], i / 10)
            engine.tick(i / 10)
            engine.data_to_send()
            while (event := engine.next_event()) is not None:
                if isinstance(event, FileRequested) and isinstance(engine, BlockSender):
                    engine.serve([b"1 L"], i / 10)


@settings(max_examples=150, deadline=None)
@given(program=lines, seed=st.integers(0, 2**32), fault=st.floats(0, 0.05))
def test_faulty_line_exact_or_clean_failure(program: list[bytes], seed: int, fault: float) -> None:
    # numbered lines, as every conversational program has (repeats are told apart)
    program = [b"%d %s" % (i, line) for i, line in enumerate(program)]
    rng = random.Random(seed)
    cfg = BlockwiseSettings(ack_timeout=1.0, idle_timeout=10.0, retries=5)
    sender = BlockSender("P.H", program, settings=cfg)
    receiver = BlockReceiver(settings=cfg)

    def line(data: bytes) -> bytes:
        out = bytearray()
        for b in data:
            r = rng.random()
            if r < fault and b in (0x06, 0x15, 0x11, 0x13, 0x03, 0x04):
                continue  # a lost handshake character (a lost data byte is a spoilt block)
            if r < 2 * fault:
                out.append(0)  # a bit error fails the parity check (7E1): the UART gives NUL
                continue
            out.append(b)
        return bytes(out)

    now = 0.0
    sender.start(now)
    receiver.start(now)
    result = None
    for _ in range(20_000):
        a, b = sender.data_to_send(), receiver.data_to_send()
        if a:
            receiver.receive_data(line(a), now)
        if b:
            sender.receive_data(line(b), now)
        for engine in (sender, receiver):
            while (event := engine.next_event()) is not None:
                if isinstance(event, FileReceived):
                    result = event.lines
                elif isinstance(event, TransferFailed):
                    result = result if result is not None else "failed"
        if receiver.done and (sender.done or result == "failed"):
            break
        if sender.done and not receiver.done and receiver.deadline is None:
            break
        if not a and not b:
            now += 0.5
            sender.tick(now)
            receiver.tick(now)
    if isinstance(result, list):
        assert result == program
