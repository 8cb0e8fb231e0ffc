"""Golden vectors: the two Haas XModem captures in docs/captures/haas-xmodem-opendnc.txt (Figures 23
and 24)."""

from __future__ import annotations

import pytest

from opendnc.xmodem.events import Completed, DataReceived, EotAnswer
from opendnc.xmodem.framing import ACK, NAK, SMALL, Mode, checksum, decode_block, encode_block
from opendnc.xmodem.haas import has_tape_delimiters, program_header, strip_padding
from opendnc.xmodem.receiver import ReceiverConfig, XmodemReceiver
from opendnc.xmodem.sender import XmodemSender
from tests.unit.xmodem.capture import load

BLOCK = 132


def _blocks(figure: int) -> list[bytes]:
    """Every block-sized record the sending side put on the wire, split into 132-byte blocks."""
    sender_is_pc = figure == 24
    out: list[bytes] = []
    for chunk in load(figure):
        if chunk.pc_wrote == sender_is_pc and len(chunk.data) >= BLOCK:
            assert len(chunk.data) % BLOCK == 0
            out += [chunk.data[i : i + BLOCK] for i in range(0, len(chunk.data), BLOCK)]
    return out


def _program() -> bytes:
    return strip_padding(b"".join(decode_block(b, crc=False).data for b in _blocks(23)))


def test_figure_23_blocks_all_verify_and_rebuild_the_program() -> None:
    blocks = _blocks(23)
    assert [b[1] for b in blocks] == list(range(1, 9))
    for raw in blocks:
        assert raw[0] == 0x01
        assert raw[1] + raw[2] == 0xFF
        assert checksum(raw[3:-1]) == raw[-1]  # every block's 8-bit sum matches
        decode_block(raw, crc=False)
    # the two sums quoted in docs/xmodem.md#golden-vectors
    assert blocks[0][-1] == 0x98
    assert blocks[-1][-1] == 0xE4
    program = _program()
    assert len(program) == 7 * SMALL + (SMALL - 48)  # last block: 80 data bytes + 48 SUB
    assert program.startswith(b"\n%\nO05555(CS390_Test_NC)\n(Using G0 which travels")
    assert program.endswith(b"N66465M30\n\n%\n")
    assert blocks[-1][3:-1].endswith(b"M30\n\n%\n" + b"\x1a" * 48)
    assert has_tape_delimiters(program)
    header = program_header(program)
    assert header is not None
    assert (header.name, header.number, header.comment) == ("O05555", 5555, "CS390_Test_NC")


def test_figure_24_carries_the_same_blocks_as_figure_23() -> None:
    sent = _blocks(24)
    # the PC sent block 1 twice (surplus NAKs) and block 2 twice (NAKed once)
    unique = [b for i, b in enumerate(sent) if i == 0 or b != sent[i - 1]]
    assert unique == _blocks(23)


def test_our_sender_encodes_exactly_the_captured_blocks() -> None:
    program = _program()
    ours = [
        encode_block(seq, program[(seq - 1) * SMALL : seq * SMALL], crc=False)
        for seq in range(1, 9)
    ]
    assert ours == _blocks(23)


def test_sender_replays_figure_24_and_accepts_can_after_eot() -> None:
    """Feed the control's bytes of Figure 24; our sender must write the captured blocks."""
    program = _program()
    sender = XmodemSender(program, Mode.CHECKSUM)
    written: list[bytes] = []
    control = [c for c in load(24) if not c.pc_wrote]
    assert control[0].data == bytes([NAK])
    assert control[1].data == bytes([NAK, NAK])
    # the first NAK starts the transfer; the two NAKs queued behind it arrive with it here,
    # and must not cause block 1 to be sent again
    sender.receive_data(control[0].data + control[1].data)
    for chunk in control[2:]:
        written.append(sender.data_to_send())
        sender.receive_data(chunk.data)
    assert sender.data_to_send() == b""
    blocks = _blocks(24)
    expected = [blocks[0], blocks[2], blocks[3], *blocks[4:], b"\x04"]
    assert written == expected  # block 2 again after the control's NAK, then EOT
    events = []
    while (event := sender.next_event()) is not None:
        events.append(event)
    assert sender.finished
    assert sender.error is None
    assert events[-1] == Completed(len(program), 8, EotAnswer.CAN)


def test_receiver_replays_figure_23() -> None:
    """Feed the control's bytes of Figure 23; our receiver must answer like the PC did."""
    receiver = XmodemReceiver(Mode.CHECKSUM, ReceiverConfig(start_interval=10.0))
    chunks = load(23)
    pc_bytes = [c.data for c in chunks if c.pc_wrote]
    control = [c.data for c in chunks if not c.pc_wrote]
    answers = [receiver.data_to_send()]
    receiver.timed_out()  # the control ignored the first NAK; 10 s later we NAK again
    answers.append(receiver.data_to_send())
    for data in control:
        receiver.receive_data(data)
        if data == b"\x04":
            receiver.timed_out()  # nothing followed the EOT within the settle time
        answers.append(receiver.data_to_send())
    assert answers == pc_bytes
    assert pc_bytes[-1] == bytes([ACK])
    data = b""
    while (event := receiver.next_event()) is not None:
        if isinstance(event, DataReceived):
            data += event.data
    assert receiver.result == Completed(len(_program()), 8)
    assert data == _program()


@pytest.mark.parametrize("keep", [False, True])
def test_receiver_keeps_padding_only_on_request(keep: bool) -> None:
    receiver = XmodemReceiver(Mode.CHECKSUM, ReceiverConfig(strip_padding=not keep))
    for raw in _blocks(23):
        receiver.receive_data(raw)
    receiver.receive_data(b"\x04")
    receiver.timed_out()
    data = b""
    while (event := receiver.next_event()) is not None:
        if isinstance(event, DataReceived):
            data += event.data
    assert data == (_program() + b"\x1a" * 48 if keep else _program())
