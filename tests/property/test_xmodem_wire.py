"""Hypothesis: sender and receiver wired in memory through random faults.

Every fault is one of: a byte flipped, a chunk cut short, a chunk lost, a chunk delivered
twice -- in either direction, on random chunks. Whatever happens, the run ends (no hang in
virtual time) and the receiver either completes with exactly the sent bytes or fails with a
typed error; it never completes with a corrupted or partial file.

(One fault per chunk: several changed bytes inside one block can cancel out in the 8-bit sum
of checksum mode -- a limit of the protocol, not of the engines.)
"""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from opendnc.errors import DncError
from opendnc.xmodem.framing import Mode
from opendnc.xmodem.receiver import ReceiverConfig, XmodemReceiver
from opendnc.xmodem.sender import SenderConfig, XmodemSender
from tests.unit.xmodem.memwire import WireResult, run_wired

FAULT_KINDS = ["flip", "cut", "lose", "twice"]


@st.composite
def fault_plan(draw: st.DrawFn) -> dict[int, tuple[str, int, int]]:
    """chunk number -> (kind, position seed, xor value)."""
    plan: dict[int, tuple[str, int, int]] = {}
    for _ in range(draw(st.integers(0, 12))):
        index = draw(st.integers(0, 60))
        plan[index] = (
            draw(st.sampled_from(FAULT_KINDS)),
            draw(st.integers(0, 2000)),
            draw(st.integers(1, 255)),
        )
    return plan


@settings(max_examples=250, deadline=None)
@given(
    data=st.binary(min_size=1, max_size=2500).map(lambda b: b.rstrip(b"\x1a") or b"x"),
    sender_mode=st.sampled_from(list(Mode)),
    receiver_mode=st.sampled_from(list(Mode)),
    plan=fault_plan(),
    byte_time=st.sampled_from([0.0, 1 / 11_520, 1 / 960]),
)
def test_faulty_wire_ends_identical_or_typed_error(
    data: bytes,
    sender_mode: Mode,
    receiver_mode: Mode,
    plan: dict[int, tuple[str, int, int]],
    byte_time: float,
) -> None:
    result = _run_faulty(data, sender_mode, receiver_mode, plan, byte_time, prepare=True)
    if result.receiver_result is not None:
        assert result.received == data
        assert result.receiver_error is None
    else:
        assert isinstance(result.receiver_error, DncError)
    if result.sender_error is not None:
        assert isinstance(result.sender_error, DncError)


@settings(max_examples=100, deadline=None)
@given(
    data=st.binary(min_size=1, max_size=5000).map(lambda b: b.rstrip(b"\x1a") or b"x"),
    mode=st.sampled_from(list(Mode)),
    plan=fault_plan(),
)
def test_prepared_blocks_change_nothing_on_the_wire(
    data: bytes, mode: Mode, plan: dict[int, tuple[str, int, int]]
) -> None:
    # the sender's prepare() builds the next block early; with the same faults (NAKs, 1K
    # fallback, retries) the bytes on the wire must be exactly those built on demand
    plain = _run_faulty(data, mode, mode, plan, 1 / 11_520, prepare=False)
    early = _run_faulty(data, mode, mode, plan, 1 / 11_520, prepare=True)
    assert early.trace == plain.trace
    assert early.received == plain.received


def _run_faulty(
    data: bytes,
    sender_mode: Mode,
    receiver_mode: Mode,
    plan: dict[int, tuple[str, int, int]],
    byte_time: float,
    *,
    prepare: bool,
) -> WireResult:
    counter = {"n": 0}

    def fault(direction: str, chunk: bytes) -> bytes:
        index = counter["n"]
        counter["n"] += 1
        if index not in plan:
            return chunk
        kind, seed, value = plan[index]
        where = seed % len(chunk)
        if kind == "flip":
            return chunk[:where] + bytes([chunk[where] ^ value]) + chunk[where + 1 :]
        if kind == "cut":
            return chunk[:where]
        if kind == "lose":
            return b""
        return chunk + chunk

    return run_wired(
        XmodemSender(data, sender_mode, SenderConfig(max_retries=6)),
        XmodemReceiver(receiver_mode, ReceiverConfig(max_retries=6)),
        fault=fault,
        byte_time=byte_time,
        keep_trace=True,
        prepare=prepare,
    )
