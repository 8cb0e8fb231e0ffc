"""The receiver's block-level NC text check (``ReceiverConfig(text_check=True)``)."""

from __future__ import annotations

from opendnc.errors import ProgramTextError, TransferError
from opendnc.sim.cable.noise import LineNoise
from opendnc.xmodem.events import Retry
from opendnc.xmodem.framing import Mode
from opendnc.xmodem.receiver import ReceiverConfig, XmodemReceiver
from opendnc.xmodem.sender import XmodemSender
from tests.sim.test_xmodem_text_check import program
from tests.unit.xmodem.memwire import WireResult, run_wired

TEXT = ReceiverConfig(text_check=True)


def wired(data: bytes, mode: Mode = Mode.CHECKSUM, seed: int | None = None) -> WireResult:
    fault = None
    if seed is not None:
        lanes = {
            "s>r": LineNoise(1e-4, 1e-4, f"{seed}:a>b"),
            "r>s": LineNoise(1e-4, 1e-4, f"{seed}:b>a"),
        }
        fault = lambda direction, chunk: lanes[direction].apply(chunk).data  # noqa: E731
    return run_wired(
        XmodemSender(data, mode), XmodemReceiver(mode, TEXT), fault=fault, byte_time=10 / 115200
    )


def text_retries(result: WireResult) -> list[str]:
    return [e.reason for e in result.receiver_events if isinstance(e, Retry) and "NC" in e.reason]


def test_blind_spot_block_is_sent_again() -> None:
    """Seed 220: block 27 passes the 8-bit sum with LF -> 0x02; the text check NAKs it."""
    data = program()
    result = wired(data, seed=220)
    assert result.receiver_error is None
    assert result.received == data
    assert text_retries(result) == [
        "block 27: not NC text, byte 0x02 (a control character) at line 160, column 21, "
        "offset 3349 (NC block 160)"
    ]


def test_bytes_that_come_twice_are_in_the_file() -> None:
    data = b"%\nO1\nG01 X1.\x02\nM30\n%\n"
    result = wired(data)
    assert isinstance(result.receiver_error, ProgramTextError)
    assert result.receiver_error.problem.offset == 12
    assert isinstance(result.sender_error, TransferError)  # cancelled by the receiver
    assert len(text_retries(result)) == 1
    assert result.received == b""


def test_problem_in_a_block_already_taken_cancels() -> None:
    """A tape code at the end of block 1 is only wrong once block 2 shows text after it."""
    data = b"%\nO1\n" + b"G01 X1.\n" * 15 + b"G1\x00" + b"G01 X2.\nM30\n%\n"
    assert data[127] == 0
    result = wired(data)
    assert isinstance(result.receiver_error, ProgramTextError)
    assert result.receiver_error.problem.offset == 127
    assert text_retries(result) == []


def test_tape_codes_around_the_program_pass() -> None:
    data = b"\x12\x00\x00" + program(100) + b"\x14"
    for mode in Mode:
        result = wired(data, mode)
        assert result.receiver_error is None
        assert result.received == data
        assert text_retries(result) == []
