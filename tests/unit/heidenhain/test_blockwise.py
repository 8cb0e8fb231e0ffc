"""The blockwise engines against each other and against hand-made wire bytes."""

from __future__ import annotations

import pytest

from opendnc.errors import InputError
from opendnc.heidenhain.blockwise import (
    ACK,
    DC1,
    DC3,
    EOT,
    ETX,
    NAK,
    BlockReceiver,
    BlockSender,
    FileReceived,
    FileRequested,
    FileSent,
    TransferFailed,
    block_check,
    encode_block,
    encode_header,
    join_lines,
    split_lines,
)


def program(n: int) -> bytes:
    lines = [b"0 BEGIN PGM P2000 MM"]
    lines += [
        b"%d L X+%d.5 Y-%d R0 F%d M3" % (i, i % 300, i % 41, 500 + i) for i in range(1, n - 1)
    ]
    lines.append(b"%d END PGM P2000 MM" % (n - 1))
    return join_lines(lines)


def run(sender: BlockSender, receiver: BlockReceiver, spoil: int | None = None) -> list[bytes]:
    """Pass bytes both ways until both are done; ``spoil`` flips a bit of that sender chunk."""
    now, chunks = 0.0, 0
    sender.start(now)
    receiver.start(now)
    for _ in range(100_000):
        a = sender.data_to_send()
        if a:
            chunks += 1
            if chunks == spoil:
                a = a[:-1] + bytes([a[-1] ^ 0x01])
            receiver.receive_data(a, now)
        b = receiver.data_to_send()
        if b:
            sender.receive_data(b, now)
        while (ev := sender.next_event()) is not None:
            if isinstance(ev, FileRequested):
                sender.serve(split_lines(program(50)), now)
        if sender.done and receiver.done and not a and not b:
            break
        if not a and not b:
            now += 1.0
            sender.tick(now)
            receiver.tick(now)
    events = []
    while (ev := receiver.next_event()) is not None:
        events.append(ev)
    assert isinstance(events[-1], FileReceived), events
    return events[-1].lines


def test_wire_format() -> None:
    header = encode_header(b"H", "PART.H")
    assert header == b"\x01HPART.HE\x17" + bytes([block_check(b"HPART.HE\x17")])
    block = encode_block(b"1 L X+10 R0 FMAX")
    assert block[0] == 0x02
    assert block[-2] == 0x17
    assert block[-1] == block_check(b"1 L X+10 R0 FMAX\x17")


def test_push_of_a_2000_line_program_is_byte_identical() -> None:
    data = program(2000)
    lines = split_lines(data)
    assert len(lines) == 2000
    got = run(BlockSender("P2000.H", lines), BlockReceiver())
    assert join_lines(got) == data


def test_request_with_k_header() -> None:
    got = run(BlockSender(None), BlockReceiver("P2000.H"))
    assert join_lines(got) == program(50)


def test_bad_block_check_is_answered_with_nak_and_resent() -> None:
    sender = BlockSender("P.H", split_lines(program(20)))
    receiver = BlockReceiver()
    got = run(sender, receiver, spoil=5)
    assert join_lines(got) == program(20)
    assert receiver.naks == 1
    assert sender.resent == 1


def test_receiver_naks_a_spoilt_line_on_the_wire() -> None:
    receiver = BlockReceiver()
    receiver.start(0.0)
    receiver.receive_data(encode_header(b"H", "A.H"), 0.0)
    assert receiver.data_to_send() == bytes([ACK])
    good = encode_block(b"1 L X+1")
    receiver.receive_data(good[:-1] + bytes([good[-1] ^ 0x40]), 0.1)
    assert receiver.data_to_send() == bytes([NAK])
    receiver.receive_data(good, 0.2)
    assert receiver.data_to_send() == bytes([ACK])
    receiver.receive_data(bytes([ETX]), 0.3)
    assert receiver.data_to_send() == bytes([EOT])
    event = receiver.next_event()
    assert isinstance(event, FileReceived)
    assert event.lines == [b"1 L X+1"]


def test_dc3_holds_the_sender_until_dc1() -> None:
    sender = BlockSender("A.H", [b"1 L X+1", b"2 L X+2"])
    sender.start(0.0)
    sender.data_to_send()
    sender.receive_data(bytes([DC3, ACK]), 0.1)
    assert sender.data_to_send() == b""  # held
    sender.receive_data(bytes([DC1]), 0.2)
    assert sender.data_to_send() == encode_block(b"1 L X+1")


def test_sender_gives_up_after_retries() -> None:
    sender = BlockSender("A.H", [b"1 L X+1"])
    sender.start(0.0)
    for i in range(4):
        assert sender.data_to_send().startswith(b"\x01H")
        sender.receive_data(bytes([NAK]), float(i))
    event = sender.next_event()
    assert isinstance(event, TransferFailed)
    assert "header" in str(event.error)


def test_sender_event_and_control_characters_in_lines_refused() -> None:
    with pytest.raises(InputError):
        split_lines(b"1 L X+1\x03\r\n")
    sender = BlockSender("A.H", [])
    sender.start(0.0)
    sender.data_to_send()
    sender.receive_data(bytes([ACK]), 0.0)
    assert sender.data_to_send() == bytes([ETX])
    sender.receive_data(bytes([EOT]), 0.0)
    assert sender.next_event() == FileSent("A.H", 0, 0)


@pytest.mark.parametrize("where", [1, 4, -2, -1])  # first text byte, middle, ETB, BCC
def test_marked_character_spoils_its_block_whatever_its_value(where: int) -> None:
    """A character the port marked as failing parity (here with its right value, as two
    errors that cancel would leave it) is refused like a bad block check."""
    receiver = BlockReceiver()
    receiver.start(0.0)
    receiver.receive_data(encode_header(b"H", "A.H"), 0.0)
    assert receiver.data_to_send() == bytes([ACK])
    good = encode_block(b"1 L X+1")
    receiver.receive_data(good, 0.1, [where % len(good)])
    assert receiver.data_to_send() == bytes([NAK])
    receiver.receive_data(good[:3], 0.2)  # a clean repeat, split with a mark after it
    receiver.receive_data(good[3:] + bytes([ETX]), 0.2, [len(good) - 3])
    assert receiver.data_to_send() == bytes([ACK])  # the marked ETX is noise, not the end
    assert receiver.next_event() is None
    receiver.receive_data(bytes([ETX]), 0.3)
    assert receiver.data_to_send() == bytes([EOT])
    event = receiver.next_event()
    assert isinstance(event, FileReceived)
    assert event.lines == [b"1 L X+1"]
