"""Sender and receiver engines wired in memory (virtual clock) and driven by hand."""

from __future__ import annotations

import random

import pytest

from opendnc.errors import PeerClosed, RemoteProtocolError, TransferError, TransportTimeout
from opendnc.xmodem.events import (
    Completed,
    DataReceived,
    Duplicate,
    EotAnswer,
    FallbackToSmall,
    Retry,
    Started,
)
from opendnc.xmodem.framing import (
    ACK,
    CAN,
    CRC_REQUEST,
    EOT,
    NAK,
    SOH,
    STX,
    Mode,
    decode_block,
    encode_block,
)
from opendnc.xmodem.receiver import PlainTextStart, ReceiverConfig, XmodemReceiver
from opendnc.xmodem.sender import SenderConfig, SenderState, XmodemSender
from tests.unit.xmodem.memwire import run_wired


def _data(n: int, seed: int = 1) -> bytes:
    data = random.Random(seed).randbytes(n)
    return data.rstrip(b"\x1a")  # a trailing SUB is indistinguishable from padding


@pytest.mark.parametrize("mode", list(Mode))
@pytest.mark.parametrize("size", [1, 127, 128, 129, 896, 897, 1024, 1025, 40_000])
def test_clean_transfer_all_modes(mode: Mode, size: int) -> None:
    data = _data(size)
    result = run_wired(XmodemSender(data, mode), XmodemReceiver(mode))
    assert result.received == data
    assert result.sender_result is not None
    assert result.sender_result.size == len(data)
    assert result.receiver_result == Completed(len(data), result.sender_result.blocks)


def test_block_numbers_wrap_255_to_0() -> None:
    data = _data(300 * 128)
    result = run_wired(XmodemSender(data, Mode.CRC), XmodemReceiver(Mode.CRC), keep_trace=True)
    assert result.received == data
    seqs = [chunk[1] for _, d, chunk in result.trace if d == "s>r" and chunk[0] == SOH]
    assert seqs[254:258] == [255, 0, 1, 2]
    assert len(seqs) == 300


def test_1k_sender_sends_large_blocks_and_a_short_tail() -> None:
    data = _data(3 * 1024 + 300)
    result = run_wired(XmodemSender(data, Mode.ONE_K), XmodemReceiver(Mode.CRC), keep_trace=True)
    assert result.received == data
    starts = [chunk[0] for _, d, chunk in result.trace if d == "s>r" and len(chunk) > 1]
    assert starts == [STX, STX, STX, SOH, SOH, SOH]  # 300-byte tail: three 128-byte blocks


def test_1k_sender_falls_back_to_checksum_128_on_nak_start() -> None:
    data = _data(5000)
    result = run_wired(
        XmodemSender(data, Mode.ONE_K), XmodemReceiver(Mode.CHECKSUM), keep_trace=True
    )
    assert result.received == data
    blocks = [chunk for _, d, chunk in result.trace if d == "s>r" and len(chunk) > 1]
    assert all(len(b) == 132 for b in blocks)
    assert Started(Mode.ONE_K, False) in result.sender_events


def test_1k_sender_falls_back_to_128_after_repeated_naks() -> None:
    data = _data(4096)
    naks = {"left": 3}

    def reject_large(direction: str, chunk: bytes) -> bytes:
        # a receiver that cannot take 1K blocks: garble them until the sender gives in
        if direction == "s>r" and chunk[0] == STX and naks["left"]:
            naks["left"] -= 1
            return chunk[:5] + bytes([chunk[5] ^ 0xFF]) + chunk[6:]
        return chunk

    result = run_wired(XmodemSender(data, Mode.ONE_K), XmodemReceiver(Mode.CRC), fault=reject_large)
    assert result.received == data
    assert FallbackToSmall(1) in result.sender_events
    assert result.sender_result is not None
    assert result.sender_result.blocks == 32


def test_checksum_sender_ignores_c_and_crc_receiver_falls_back() -> None:
    data = _data(1000)
    result = run_wired(XmodemSender(data, Mode.CHECKSUM), XmodemReceiver(Mode.CRC))
    assert result.received == data
    assert result.elapsed > 3 * ReceiverConfig().start_interval  # three 'C' went unanswered


def test_lost_ack_gives_a_duplicate_that_is_acked_and_dropped() -> None:
    data = _data(1000)
    state = {"acks": 0}

    def lose_third_ack(direction: str, chunk: bytes) -> bytes:
        if direction == "r>s" and chunk == bytes([ACK]):
            state["acks"] += 1
            if state["acks"] == 3:
                return b""
        return chunk

    result = run_wired(XmodemSender(data, Mode.CRC), XmodemReceiver(Mode.CRC), fault=lose_third_ack)
    assert result.received == data
    assert Duplicate(3) in result.receiver_events
    assert any(isinstance(e, Retry) and e.seq == 3 for e in result.sender_events)


def test_corrupted_block_is_naked_and_resent() -> None:
    data = _data(5000)
    hit = {"done": False}

    def corrupt_once(direction: str, chunk: bytes) -> bytes:
        if direction == "s>r" and len(chunk) > 100 and chunk[1] == 4 and not hit["done"]:
            hit["done"] = True
            return chunk[:50] + bytes([chunk[50] ^ 1]) + chunk[51:]
        return chunk

    for mode in Mode:
        hit["done"] = False
        result = run_wired(XmodemSender(data, mode), XmodemReceiver(mode), fault=corrupt_once)
        assert result.received == data
        assert any(isinstance(e, Retry) and e.seq == 4 for e in result.receiver_events)


def test_dropped_byte_inside_a_block_is_naked_after_silence() -> None:
    data = _data(600)
    hit = {"done": False}

    def drop_one(direction: str, chunk: bytes) -> bytes:
        if direction == "s>r" and len(chunk) > 100 and not hit["done"]:
            hit["done"] = True
            return chunk[:10] + chunk[11:]
        return chunk

    result = run_wired(XmodemSender(data, Mode.CRC), XmodemReceiver(Mode.CRC), fault=drop_one)
    assert result.received == data
    assert Retry(1, 1, "incomplete block") in result.receiver_events


def test_noise_that_turns_soh_into_eot_never_truncates_the_file() -> None:
    data = _data(1000)
    hit = {"done": False}

    def soh_to_eot(direction: str, chunk: bytes) -> bytes:
        if direction == "s>r" and len(chunk) > 100 and chunk[1] == 5 and not hit["done"]:
            hit["done"] = True
            return bytes([EOT]) + chunk[1:]
        return chunk

    result = run_wired(XmodemSender(data, Mode.CRC), XmodemReceiver(Mode.CRC), fault=soh_to_eot)
    assert result.received == data


def test_retry_limit_ends_both_sides_with_typed_errors() -> None:
    def garble(direction: str, chunk: bytes) -> bytes:
        return (
            bytes([chunk[0]]) + bytes(b ^ 0x55 for b in chunk[1:]) if direction == "s>r" else chunk
        )

    result = run_wired(XmodemSender(_data(500), Mode.CRC), XmodemReceiver(Mode.CRC), fault=garble)
    assert isinstance(result.receiver_error, TransferError)
    assert "failed 11 times" in str(result.receiver_error)
    assert isinstance(result.sender_error, TransferError)
    assert result.received == b""


def test_sender_retry_limit_on_silence() -> None:
    sender = XmodemSender(b"x" * 10, Mode.CRC, SenderConfig(max_retries=2))
    sender.receive_data(bytes([CRC_REQUEST]))
    first = sender.data_to_send()
    for _ in range(2):
        sender.timed_out()
        assert sender.data_to_send() == first
    sender.timed_out()
    assert sender.data_to_send() == bytes([CAN, CAN, CAN])
    assert isinstance(sender.error, TransferError)


def test_receiver_cancels_sender_with_can_can() -> None:
    sender = XmodemSender(b"x" * 300, Mode.CRC)
    sender.receive_data(bytes([CRC_REQUEST]))
    sender.data_to_send()
    sender.receive_data(bytes([CAN]))
    assert not sender.finished  # one CAN may be noise
    sender.receive_data(bytes([CAN]))
    assert isinstance(sender.error, TransferError)
    assert "receiver cancelled" in str(sender.error)
    assert sender.data_to_send() == b""


def test_sender_cancels_receiver_with_can_can() -> None:
    receiver = XmodemReceiver(Mode.CRC)
    receiver.data_to_send()
    receiver.receive_data(encode_block(1, b"abc", crc=True))
    assert receiver.data_to_send() == bytes([ACK])
    receiver.receive_data(bytes([CAN, CAN]))
    receiver.timed_out()  # settle
    assert isinstance(receiver.error, TransferError)
    assert "sender cancelled" in str(receiver.error)


def test_local_cancel_sends_can_both_ways() -> None:
    for engine in (XmodemSender(b"x", Mode.CRC), XmodemReceiver(Mode.CRC)):
        engine.data_to_send()
        engine.cancel()
        assert engine.data_to_send() == bytes([CAN, CAN, CAN])
        assert isinstance(engine.error, TransferError)


def test_haas_can_after_eot_counts_as_success() -> None:
    sender = XmodemSender(b"%\nO00001\nM30\n%\n", Mode.CHECKSUM)
    sender.receive_data(bytes([NAK]))
    sender.data_to_send()
    sender.receive_data(bytes([ACK]))
    assert sender.data_to_send() == bytes([EOT])
    sender.receive_data(bytes([CAN, CAN, CAN]))
    assert sender.result == Completed(15, 1, EotAnswer.CAN)


def test_can_before_the_end_is_a_failure() -> None:
    sender = XmodemSender(b"x" * 1000, Mode.CHECKSUM)
    sender.receive_data(bytes([NAK]))
    sender.receive_data(bytes([ACK]))
    sender.receive_data(bytes([CAN, CAN, CAN]))
    assert isinstance(sender.error, TransferError)


def test_eot_without_answer_finishes_after_retries() -> None:
    sender = XmodemSender(b"x", Mode.CRC, SenderConfig(eot_retries=2))
    sender.receive_data(bytes([CRC_REQUEST]))
    sender.data_to_send()
    sender.receive_data(bytes([ACK]))
    sent = [sender.data_to_send()]
    for _ in range(3):
        sender.timed_out()
        sent.append(sender.data_to_send())
    assert sent == [bytes([EOT]), bytes([EOT]), bytes([EOT]), b""]
    assert sender.result == Completed(1, 1, EotAnswer.NONE)


def test_link_closed_after_eot_is_success_before_is_error() -> None:
    sender = XmodemSender(b"x", Mode.CRC)
    sender.receive_data(bytes([CRC_REQUEST]))
    sender.receive_data(bytes([ACK]))
    sender.peer_closed()
    assert sender.result is not None
    assert sender.result.eot_answer is EotAnswer.CLOSED
    early = XmodemSender(b"x" * 500, Mode.CRC)
    early.receive_data(bytes([CRC_REQUEST]))
    early.peer_closed()
    assert isinstance(early.error, PeerClosed)
    receiver = XmodemReceiver(Mode.CRC)
    receiver.peer_closed()
    assert isinstance(receiver.error, PeerClosed)


def test_eot_naked_forever_is_an_error() -> None:
    sender = XmodemSender(b"x", Mode.CRC, SenderConfig(max_retries=2))
    sender.receive_data(bytes([CRC_REQUEST]))
    sender.receive_data(bytes([ACK]))
    for _ in range(3):
        sender.receive_data(bytes([NAK]))
    assert isinstance(sender.error, TransferError)


def test_start_timeouts_are_typed() -> None:
    sender = XmodemSender(b"x", Mode.CRC, SenderConfig(start_timeout=25, ack_timeout=10))
    for _ in range(3):
        sender.timed_out()
    assert isinstance(sender.error, TransportTimeout)
    receiver = XmodemReceiver(Mode.CHECKSUM, ReceiverConfig(start_timeout=9, start_interval=3))
    requests = [receiver.data_to_send()]
    while not receiver.finished:
        receiver.timed_out()
        requests.append(receiver.data_to_send())
    assert requests == [bytes([NAK])] * 3 + [bytes([CAN, CAN, CAN])]
    assert isinstance(receiver.error, TransportTimeout)


def test_receiver_repeats_c_then_falls_back_to_nak() -> None:
    receiver = XmodemReceiver(Mode.CRC, ReceiverConfig(crc_tries=2))
    sent = [receiver.data_to_send()]
    for _ in range(3):
        receiver.timed_out()
        sent.append(receiver.data_to_send())
    assert sent == [b"C", b"C", bytes([NAK]), bytes([NAK])]
    receiver.receive_data(encode_block(1, b"hi", crc=False))
    assert receiver.data_to_send() == bytes([ACK])


def test_out_of_order_block_cancels_with_a_clear_error() -> None:
    receiver = XmodemReceiver(Mode.CRC)
    receiver.data_to_send()
    receiver.receive_data(encode_block(1, b"a", crc=True))
    receiver.data_to_send()
    receiver.receive_data(encode_block(3, b"c", crc=True))
    assert isinstance(receiver.error, RemoteProtocolError)
    assert "block 3 arrived while block 2 was expected" in str(receiver.error)
    assert receiver.data_to_send() == bytes([CAN, CAN, CAN])


def test_eot_before_any_block_is_an_error() -> None:
    receiver = XmodemReceiver(Mode.CRC)
    receiver.receive_data(bytes([EOT]))
    receiver.timed_out()
    assert isinstance(receiver.error, TransferError)


def test_garbage_while_idle_is_ignored_and_leading_noise_skipped() -> None:
    receiver = XmodemReceiver(Mode.CRC)
    receiver.data_to_send()
    receiver.receive_data(b"\x00\xffC")
    assert receiver.data_to_send() == b""
    receiver.receive_data(b"\x7f\x7f" + encode_block(1, b"a", crc=True))
    assert receiver.data_to_send() == bytes([ACK])


def test_receiver_handles_a_block_split_in_many_reads() -> None:
    receiver = XmodemReceiver(Mode.ONE_K)
    receiver.data_to_send()
    raw = encode_block(1, b"z" * 1024, crc=True, large=True)
    for i in range(0, len(raw), 7):
        receiver.receive_data(raw[i : i + 7])
    assert receiver.data_to_send() == bytes([ACK])
    receiver.receive_data(bytes([EOT]))
    receiver.timed_out()
    events = []
    while (event := receiver.next_event()) is not None:
        events.append(event)
    assert DataReceived(b"z" * 1024) in events


def test_sender_blocks_decode_to_the_file() -> None:
    data = _data(2000)
    sender = XmodemSender(data, Mode.ONE_K)
    sender.receive_data(b"C")
    got = b""
    while not sender.finished:
        out = sender.data_to_send()
        if out == bytes([EOT]):
            sender.receive_data(bytes([ACK]))
            break
        got += decode_block(out, crc=True).data
        sender.receive_data(bytes([ACK]))
    assert got.rstrip(b"\x1a") == data


def test_turnaround_pause_is_a_non_listening_timer() -> None:
    sender = XmodemSender(b"x" * 300, Mode.CRC, SenderConfig(turnaround=0.001))
    sender.receive_data(b"C")
    assert sender.data_to_send() == b""  # the pause applies before block 1 as well
    sender.timed_out()
    assert decode_block(sender.data_to_send(), crc=True).seq == 1
    sender.receive_data(bytes([ACK]))
    assert sender.data_to_send() == b""
    assert sender.timer is not None
    assert not sender.timer.listen
    sender.timed_out()
    assert decode_block(sender.data_to_send(), crc=True).seq == 2


def test_receiver_answers_a_complete_transfer_as_configured() -> None:
    """A Haas answers the final EOT with CAN CAN CAN (``eot_answer``), a PC with ACK."""
    for answer, wire in ((EotAnswer.ACK, bytes([ACK])), (EotAnswer.CAN, bytes([CAN] * 3))):
        receiver = XmodemReceiver(Mode.CHECKSUM, ReceiverConfig(eot_answer=answer))
        receiver.data_to_send()
        receiver.receive_data(encode_block(1, b"G0", crc=False))
        assert receiver.data_to_send() == bytes([ACK])
        receiver.receive_data(bytes([EOT]))
        receiver.timed_out()  # the line stayed quiet after the EOT
        assert receiver.data_to_send() == wire
        assert receiver.result == Completed(2, 1, answer)
    sender = XmodemSender(b"G0", Mode.CHECKSUM)
    assert (
        run_wired(
            sender, XmodemReceiver(Mode.CHECKSUM, ReceiverConfig(eot_answer=EotAnswer.CAN))
        ).sender_error
        is None
    )
    assert sender.result is not None
    assert sender.result.eot_answer is EotAnswer.CAN


def test_receiver_text_start_ends_on_plain_text_only_when_set() -> None:
    receiver = XmodemReceiver(Mode.CHECKSUM, ReceiverConfig(text_start=True))
    receiver.data_to_send()
    receiver.receive_data(b"\r\n\x11")  # filler says nothing yet
    assert not receiver.finished
    receiver.receive_data(b"%\nO1000\n")
    assert isinstance(receiver.error, PlainTextStart)
    assert receiver.error.text == b"%\nO1000\n"
    assert receiver.data_to_send() == b""  # the text is not cancelled on the wire
    plain = XmodemReceiver(Mode.CHECKSUM)
    plain.data_to_send()
    plain.receive_data(b"%\nO1000\n")  # without the setting: noise while idle
    assert not plain.finished
    started = XmodemReceiver(Mode.CHECKSUM, ReceiverConfig(text_start=True))
    started.data_to_send()
    started.receive_data(b"\n" + encode_block(1, b"G0", crc=False))
    assert started.data_to_send() == bytes([ACK])


def test_the_rest_of_a_start_request_burst_does_not_run_the_sender_ahead() -> None:
    data = bytes(range(32, 127)) * 20  # 15 blocks
    sender = XmodemSender(data, Mode.CHECKSUM)
    receiver = XmodemReceiver(Mode.CHECKSUM, ReceiverConfig(crc_tries=0))
    assert receiver.data_to_send() == bytes([NAK])  # its start request; a Haas repeats it
    sender.receive_data(bytes([NAK]))  # the sender reads the first NAK of a burst alone,
    wire = [sender.data_to_send()]  # sends block 1,
    sender.receive_data(bytes([NAK, NAK]))  # and the rest of the burst after that
    copies = sender.data_to_send()
    wire += [copies[i : i + 132] for i in range(0, len(copies), 132)]
    acks = b""
    for frame in wire:  # the receiver reads each copy on its own and ACKs each
        receiver.receive_data(frame)
        acks += receiver.data_to_send()
    sender.receive_data(acks)  # the ACKs reach the sender together
    receiver.receive_data(sender.data_to_send())  # what it sent reaches the receiver together
    sender.receive_data(receiver.data_to_send())
    receiver.timed_out()  # a block the receiver dropped as queued after another: NAK
    sender.receive_data(receiver.data_to_send())
    receiver.receive_data(sender.data_to_send())
    assert receiver.error is None, receiver.error  # seen: "block 4 arrived while block 3 ..."
    # the sender lets the copies' answers pass, then goes on: the file arrives whole
    for _ in range(100):
        if sender.finished and receiver.finished:
            break
        out = sender.data_to_send()
        if out:
            receiver.receive_data(out)
        elif sender.state is SenderState.SETTLE:
            sender.timed_out()  # the wait for the copies' answers ends
        else:
            receiver.timed_out()  # e.g. a receiver that answers EOT after a pause
        sender.receive_data(receiver.data_to_send())
    assert sender.error is None, sender.error
    assert receiver.error is None, receiver.error
    received = b""
    while (event := receiver.next_event()) is not None:
        if isinstance(event, DataReceived):
            received += event.data
    assert received.rstrip(b"\x1a") == data  # the last block is padded with SUB
