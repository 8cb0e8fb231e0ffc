"""Faults that made a noisy line skip, truncate or duplicate blocks, replayed without timing.

The virtual cable's faults depend only on the seed and on a byte's position in its direction
(opendnc.sim.cable.noise), so a cable run can be replayed against the engines in memory. The
seeds below (bit-error rate 1e-4, drop rate 1e-4, the 20,160-byte program of the text-check
test) broke transfers before the fixes: a lost ACK made the sender's resend and the receiver's
NAK cross (both waited 10 s), and a sender that fell back to 128-byte blocks after a lost ACK
had the rest of a 1K block taken for new data.
"""

from __future__ import annotations

import pytest

from opendnc.sim.cable.noise import LineNoise
from opendnc.xmodem.events import Duplicate, FallbackToSmall
from opendnc.xmodem.framing import ACK, Mode
from opendnc.xmodem.receiver import XmodemReceiver
from opendnc.xmodem.sender import SenderConfig, XmodemSender
from tests.sim.test_xmodem_text_check import program
from tests.unit.xmodem.memwire import Fault, WireResult, run_wired

DATA = program()
BYTE_TIME = 10 / 115200


def cable(seed: int) -> Fault:
    lanes = {
        "s>r": LineNoise(1e-4, 1e-4, f"{seed}:a>b"),
        "r>s": LineNoise(1e-4, 1e-4, f"{seed}:b>a"),
    }
    return lambda direction, data: lanes[direction].apply(data).data


@pytest.mark.parametrize(
    ("mode", "seed", "before"),
    [
        (Mode.CRC, 2, "sender out of step: transfer cancelled"),
        (Mode.CRC, 1073, "last block lost, both ends reported success"),
        (Mode.CRC, 1248, "last block lost, both ends reported success"),
        (Mode.ONE_K, 94, "896 bytes repeated, both ends reported success"),
        (Mode.ONE_K, 648, "896 bytes repeated, both ends reported success"),
        (Mode.CHECKSUM, 2, "sender out of step: transfer cancelled"),
    ],
)
def test_noisy_cable_seed_delivers_the_file(mode: Mode, seed: int, before: str) -> None:
    result = run_wired(
        XmodemSender(DATA, mode), XmodemReceiver(mode), fault=cable(seed), byte_time=BYTE_TIME
    )
    assert result.receiver_error is None, f"{result.receiver_error} (before the fix: {before})"
    assert result.sender_error is None
    assert result.received == DATA, before


def ack_fault(number: int, replace: bytes) -> Fault:
    """Replace the ``number``-th ACK from the receiver (1-based) by ``replace``."""
    seen = 0

    def fault(direction: str, data: bytes) -> bytes:
        nonlocal seen
        if direction == "r>s" and data == bytes([ACK]):
            seen += 1
            if seen == number:
                return replace
        return data

    return fault


def run_1k(fault: Fault) -> WireResult:
    sender = XmodemSender(DATA[:6000], Mode.ONE_K, SenderConfig(fallback_after=1))
    return run_wired(sender, XmodemReceiver(Mode.ONE_K), fault=fault, byte_time=BYTE_TIME)


def test_fallback_after_a_lost_ack_repeats_no_data() -> None:
    """The ACK of block 3 vanishes; the receiver's timeout NAK makes the sender re-cut it."""
    result = run_1k(ack_fault(3, b""))
    assert any(isinstance(e, FallbackToSmall) for e in result.sender_events)
    assert sum(isinstance(e, Duplicate) for e in result.receiver_events) == 8
    assert result.receiver_error is None
    assert result.received == DATA[:6000]


def test_no_fallback_after_a_garbled_answer() -> None:
    """An ACK turned into EOT by noise may have been the ACK: the block is resent whole."""
    result = run_1k(ack_fault(3, b"\x04"))
    assert not any(isinstance(e, FallbackToSmall) for e in result.sender_events)
    assert result.received == DATA[:6000]


def test_sender_waits_longer_than_the_receiver() -> None:
    """After a lost ACK the receiver's NAK (10 s) comes before the sender's own resend."""
    result = run_wired(
        XmodemSender(DATA[:3000], Mode.CRC),
        XmodemReceiver(Mode.CRC),
        fault=ack_fault(2, b""),
        byte_time=BYTE_TIME,
        keep_trace=True,
    )
    assert result.received == DATA[:3000]
    block_2 = [t for t, d, data in result.trace if d == "s>r" and data[:2] == b"\x01\x02"]
    assert len(block_2) == 2  # sent, then resent once on the receiver's NAK: no crossing
    assert 10 <= block_2[1] - block_2[0] < 11
