"""Unit tests of the serial LSV2 link engine (docs/lsv2-serial.md)."""

from __future__ import annotations

import pytest

from opendnc.errors import DncError, InputError, TransportError, TransportTimeout
from opendnc.lsv2.framing import Frame, encode_serial_frame
from opendnc.lsv2.serial_link import (
    HostStatus,
    LinkChecked,
    LinkFailed,
    LinkRole,
    LinkTiming,
    SerialLink,
    SerialLinkError,
    TelegramReceived,
    TelegramSent,
    describe_link_bytes,
)
from tests.unit.lsv2.serial_line import exchange

ENQ, EOT, NAK = b"\x05", b"\x04", b"\x15"
READY, RECEIVED = b"\x10\x30", b"\x10\x31"
LOGIN = b"\x10\x02A_LGINSPECT\x00\x10\x03\x40"  # seed capture, step 5
T_OK = b"\x10\x02T_OK\x10\x03\x0c"  # seed capture, step 10


def test_seed_exchange_from_the_client_side() -> None:
    """Steps 1-13 of the observed TNCremo <-> TNC 320 exchange, driven by hand."""
    # with a telegram queued, the next ENQ follows the link check without EOT (steps 3-4)
    pc = SerialLink(LinkRole.CLIENT)
    pc.check_link(0.0)
    pc.send(Frame("A_LG", b"INSPECT\x00"), 0.0)
    assert pc.data_to_send() == ENQ  # 1
    pc.receive_data(READY, 0.01)  # 2
    assert pc.data_to_send() == ENQ  # 3
    pc.receive_data(READY, 0.02)  # 4
    assert pc.data_to_send() == LOGIN  # 5
    pc.receive_data(RECEIVED, 0.03)  # 6
    assert pc.data_to_send() == EOT  # 7
    assert pc.next_event() == LinkChecked()
    assert pc.next_event() == TelegramSent(Frame("A_LG", b"INSPECT\x00"), 1)
    pc.receive_data(ENQ, 0.04)  # 8
    assert pc.data_to_send() == READY  # 9
    pc.receive_data(T_OK, 0.05)  # 10
    assert pc.data_to_send() == RECEIVED  # 11
    assert pc.next_event() == TelegramReceived(Frame("T_OK"))
    pc.send(Frame("R_VR"), 0.05)  # queued until the control's EOT
    assert pc.data_to_send() == b""
    pc.receive_data(EOT, 0.06)  # 12
    assert pc.data_to_send() == ENQ  # 13
    assert pc.idle is False


def test_link_check_alone_releases_the_peer_with_eot() -> None:
    pc = SerialLink(LinkRole.CLIENT)
    pc.check_link(0.0)
    pc.data_to_send()
    pc.receive_data(READY, 0.01)
    assert pc.next_event() == LinkChecked()
    assert pc.data_to_send() == EOT
    assert pc.idle


def test_seed_exchange_from_the_control_side() -> None:
    tnc = SerialLink(LinkRole.CONTROL)
    tnc.receive_data(ENQ, 0.0)
    assert tnc.data_to_send() == READY  # 2
    tnc.receive_data(ENQ, 0.01)
    assert tnc.data_to_send() == READY  # 4
    tnc.receive_data(LOGIN, 0.02)
    assert tnc.data_to_send() == RECEIVED  # 6
    assert tnc.next_event() == TelegramReceived(Frame("A_LG", b"INSPECT\x00"))
    tnc.send(Frame("T_OK"), 0.02)
    assert tnc.data_to_send() == b""  # not before the client's EOT
    tnc.receive_data(EOT, 0.03)  # 7
    assert tnc.data_to_send() == ENQ  # 8
    tnc.receive_data(READY, 0.04)  # 9
    assert tnc.data_to_send() == T_OK  # 10
    tnc.receive_data(RECEIVED, 0.05)  # 11
    assert tnc.data_to_send() == EOT  # 12
    assert tnc.next_event() == TelegramSent(Frame("T_OK"), 1)
    assert tnc.idle


def test_bad_bcc_is_answered_with_nak_and_the_sender_repeats() -> None:
    tnc = SerialLink(LinkRole.CONTROL)
    tnc.receive_data(ENQ, 0.0)
    tnc.data_to_send()
    tnc.receive_data(LOGIN[:-1] + b"\x41", 0.01)
    assert tnc.data_to_send() == NAK
    assert tnc.next_event() is None
    assert tnc.stats.naks_sent == 1

    pc = SerialLink(LinkRole.CLIENT)
    pc.send(Frame("A_LG", b"INSPECT\x00"), 0.0)
    pc.data_to_send()
    pc.receive_data(READY, 0.0)
    assert pc.data_to_send() == LOGIN
    pc.receive_data(NAK, 0.1)
    assert pc.data_to_send() == EOT + ENQ  # end, then the whole transmission again
    pc.receive_data(READY, 0.2)
    assert pc.data_to_send() == LOGIN
    pc.receive_data(RECEIVED, 0.3)
    assert pc.data_to_send() == EOT
    assert pc.next_event() == TelegramSent(Frame("A_LG", b"INSPECT\x00"), 2)


def test_retries_exhausted_gives_typed_error_with_host_status() -> None:
    pc = SerialLink(LinkRole.CLIENT, retries=2)
    pc.send(Frame("R_VR"), 0.0)
    for i in range(3):
        assert pc.data_to_send().endswith(ENQ)
        pc.receive_data(READY, i + 0.1)
        pc.data_to_send()
        pc.receive_data(NAK, i + 0.2)
    assert pc.data_to_send() == EOT
    event = pc.next_event()
    assert isinstance(event, LinkFailed)
    assert event.error.status is HostStatus.TX_ERROR
    assert isinstance(event.error, TransportError)
    assert "R_VR given up after 3 tries" in str(event.error)
    assert pc.idle


def test_silent_peer_times_out_with_no_enq_after_time1() -> None:
    pc = SerialLink(LinkRole.CLIENT, timing=LinkTiming(time1=0.5), retries=1)
    pc.send(Frame("R_VR"), 0.0)
    assert pc.data_to_send() == ENQ
    assert pc.deadline == 0.5
    pc.tick(0.4)
    assert pc.data_to_send() == b""
    pc.tick(0.5)
    assert pc.data_to_send() == ENQ  # second try
    pc.tick(1.0)
    assert pc.data_to_send() == EOT
    event = pc.next_event()
    assert isinstance(event, LinkFailed)
    assert event.error.status is HostStatus.NO_ENQ
    assert isinstance(event.error, TransportTimeout)
    assert isinstance(event.error, DncError)
    assert "baud rate" in str(event.error)


def test_collision_client_yields_and_sends_afterwards() -> None:
    pc = SerialLink(LinkRole.CLIENT)
    tnc = SerialLink(LinkRole.CONTROL)
    pc.send(Frame("R_VR"), 0.0)
    tnc.send(Frame("M_CC", b"\x00\x1b"), 0.0)
    assert pc.data_to_send() == ENQ
    assert tnc.data_to_send() == ENQ
    pc.receive_data(ENQ, 0.01)
    tnc.receive_data(ENQ, 0.01)
    assert pc.data_to_send() == READY  # the PC yields
    assert tnc.data_to_send() == b""  # the control keeps waiting
    tnc.receive_data(READY, 0.02)
    pc.receive_data(tnc.data_to_send(), 0.03)
    tnc.receive_data(pc.data_to_send(), 0.04)
    pc.receive_data(tnc.data_to_send(), 0.05)  # EOT
    assert pc.next_event() == TelegramReceived(Frame("M_CC", b"\x00\x1b"))
    assert pc.data_to_send() == ENQ  # now its own telegram
    assert pc.stats.collisions == 1


def test_timing_range_is_enforced() -> None:
    LinkTiming(0.001, 3.6, 1.0)
    with pytest.raises(InputError):
        LinkTiming(time0=4.0)
    with pytest.raises(InputError):
        LinkTiming(time2=0.0)


def test_garbage_between_frames_is_ignored() -> None:
    tnc = SerialLink(LinkRole.CONTROL)
    tnc.receive_data(b"\xff\x00\x10\x99garbage", 0.0)
    assert tnc.data_to_send() == b""
    tnc.receive_data(ENQ, 0.0)
    assert tnc.data_to_send() == READY
    tnc.receive_data(b"\x42\x06" + LOGIN, 0.1)
    assert tnc.data_to_send() == RECEIVED
    assert tnc.next_event() == TelegramReceived(Frame("A_LG", b"INSPECT\x00"))
    assert tnc.stats.garbage >= 5


def test_dle_inside_payload_is_stuffed_and_checked_unstuffed() -> None:
    frame = Frame("S_FL", bytes(range(256)) + b"\x10\x10\x03\x10")
    out = exchange([frame.payload])
    assert out.failure is None
    assert out.answers == [frame.payload]


def test_clean_line_request_answer_sequence() -> None:
    requests = [bytes([i]) * i for i in range(1, 40)]
    out = exchange(requests, link_check=True)
    assert out.failure is None
    assert out.answers == requests
    assert out.served == requests
    assert out.client.stats.retries == 0
    assert out.control.stats.garbage == 0


def test_error_type_carries_status() -> None:
    err = SerialLinkError(HostStatus.WRONG_BCC, "x")
    assert err.status == 6
    assert "block check character wrong" in str(err)


def test_describe_link_bytes() -> None:
    assert describe_link_bytes(ENQ + READY + LOGIN + EOT) == (
        "ENQ DLE 0 DLE STX 41 5F 4C 47 49 4E 53 50 45 43 54 00 DLE ETX 40 EOT"
    )


def _client_waiting_for_dle1() -> SerialLink:
    pc = SerialLink(LinkRole.CLIENT)
    pc.send(Frame("A_LG", b"INSPECT\x00"), 0.0)
    assert pc.data_to_send() == ENQ
    pc.receive_data(READY, 0.01)
    assert pc.data_to_send() == LOGIN
    return pc


def test_enq_instead_of_dle1_then_no_telegram_repeats_ours() -> None:
    """A NAK with one bit changed reads ENQ: it must not count as an acknowledgement."""
    pc = _client_waiting_for_dle1()
    pc.receive_data(bytes([NAK[0] ^ 0x10]), 0.1)  # NAK, bit 4 flipped: ENQ
    assert pc.data_to_send() == READY  # yields, in case the control moved on
    assert pc.next_event() is None
    pc.tick(pc.deadline or 0.0)  # LSV2TIME2: no DLE STX came
    # A whole block may have been lost: give the control LSV2TIME1 to send it again before
    # repeating ours (docs/lsv2-serial.md, "Equal telegrams in a row").
    assert pc.data_to_send() == b""
    assert pc.deadline == pytest.approx(0.1 + 1.0 + 3.0)
    pc.tick(pc.deadline or 0.0)
    assert pc.data_to_send() == ENQ  # the same telegram, second try
    assert pc.next_event() is None
    pc.receive_data(READY, 4.2)
    assert pc.data_to_send() == LOGIN
    pc.receive_data(RECEIVED, 4.3)
    assert pc.data_to_send() == EOT
    assert pc.next_event() == TelegramSent(Frame("A_LG", b"INSPECT\x00"), 2)


def test_enq_instead_of_dle1_then_a_new_telegram_acknowledges_ours() -> None:
    """The control's DLE 1 was lost and it answers: its answer proves it has our request."""
    pc = _client_waiting_for_dle1()
    pc.receive_data(ENQ, 0.1)
    assert pc.data_to_send() == READY
    pc.receive_data(T_OK, 0.2)
    assert pc.data_to_send() == RECEIVED
    assert pc.next_event() == TelegramSent(Frame("A_LG", b"INSPECT\x00"), 1)
    assert pc.next_event() == TelegramReceived(Frame("T_OK", b""))
    assert pc.stats.implicit_acks == 1
    pc.receive_data(EOT, 0.3)
    assert pc.idle


def test_block_without_its_dle_stx_is_refused_whole() -> None:
    """Payload ENQ / EOT bytes of a block whose start was lost are not handshake characters."""
    tnc = SerialLink(LinkRole.CONTROL)
    tnc.receive_data(ENQ, 0.0)
    assert tnc.data_to_send() == READY
    body = b"R_FL" + ENQ + EOT + ENQ
    block = encode_serial_frame(body)
    tnc.receive_data(block[1:], 0.01)  # the DLE of DLE STX was lost
    assert tnc.data_to_send() == NAK  # once, at the block's end; no DLE 0 for the payload ENQ
    assert tnc.next_event() is None
    tnc.receive_data(EOT + ENQ, 0.02)  # the sender repeats
    assert tnc.data_to_send() == READY
    tnc.receive_data(block, 0.03)
    assert tnc.data_to_send() == RECEIVED
    assert tnc.next_event() == TelegramReceived(Frame("R_FL", ENQ + EOT + ENQ))


def test_noise_then_dle_stx_still_starts_a_block_and_dle_dle_is_one_dle() -> None:
    tnc = SerialLink(LinkRole.CONTROL)
    tnc.receive_data(ENQ, 0.0)
    tnc.data_to_send()
    tnc.receive_data(b"\x10" + LOGIN, 0.01)  # DLE repeated before STX
    assert tnc.data_to_send() == RECEIVED
    assert tnc.next_event() == TelegramReceived(Frame("A_LG", b"INSPECT\x00"))


def test_late_nak_gets_the_enq_again_once_per_try() -> None:
    """The peer read our retry ENQ as bytes of the block it then refused: ask again at once."""
    pc = _client_waiting_for_dle1()
    pc.tick(pc.deadline or 0.0)  # no DLE 1 (LSV2TIME1)
    assert pc.data_to_send() == EOT + ENQ
    pc.receive_data(NAK, 3.5)
    assert pc.data_to_send() == ENQ
    pc.receive_data(NAK, 3.6)
    assert pc.data_to_send() == b""  # once per try; LSV2TIME1 decides after that
    pc.receive_data(READY, 3.7)
    assert pc.data_to_send() == LOGIN


# -- characters the port marked as failing their parity check (docs/lsv2-serial.md) ----------

# A program line whose two '5' both fail the parity check: delivered as NUL (INPCK without
# PARMRK), they cancel in the XOR block check.
LINE = b"R_FL5 L X+5 R0\r\n"
SPOILT = LINE.replace(b"5", b"\x00")


def _control_after_enq() -> SerialLink:
    tnc = SerialLink(LinkRole.CONTROL)
    tnc.receive_data(ENQ, 0.0)
    assert tnc.data_to_send() == READY
    return tnc


def test_two_nuls_from_parity_errors_pass_the_bcc_unmarked() -> None:
    """The hole the marks close: the altered block is accepted as good."""
    sent = encode_serial_frame(Frame("S_FL", LINE))
    seen = sent.replace(b"5", b"\x00")
    assert seen[-1] == sent[-1]  # same BCC
    tnc = _control_after_enq()
    tnc.receive_data(seen, 0.01)
    assert tnc.data_to_send() == RECEIVED
    assert tnc.next_event() == TelegramReceived(Frame("S_FL", SPOILT))


@pytest.mark.parametrize("chunk", [1, 3, 1000])
def test_marked_characters_spoil_their_block(chunk: int) -> None:
    sent = encode_serial_frame(Frame("S_FL", LINE))
    seen = sent.replace(b"5", b"\x00")
    bad = [i for i, c in enumerate(sent) if c == ord("5")]
    tnc = _control_after_enq()
    for start in range(0, len(seen), chunk):
        part = seen[start : start + chunk]
        tnc.receive_data(part, 0.01, [i - start for i in bad if start <= i < start + chunk])
    assert tnc.data_to_send() == NAK
    assert tnc.next_event() is None
    assert tnc.stats.line_errors == 2
    # the sender repeats: a clean block is taken
    tnc.receive_data(EOT + ENQ, 0.02)
    assert tnc.data_to_send() == READY
    tnc.receive_data(sent, 0.03)
    assert tnc.data_to_send() == RECEIVED
    assert tnc.next_event() == TelegramReceived(Frame("S_FL", LINE))


def test_marked_bcc_or_dle_of_dle_etx_spoils_the_block() -> None:
    sent = encode_serial_frame(Frame("T_OK"))
    tnc = _control_after_enq()
    tnc.receive_data(sent, 0.01, [len(sent) - 1])  # the BCC, even with its right value
    assert tnc.data_to_send() == NAK
    tnc = _control_after_enq()
    tnc.receive_data(sent, 0.01, [len(sent) - 3])  # the DLE of DLE ETX: no end seen
    assert tnc.data_to_send() == b""
    tnc.tick(0.01 + 3.0)  # LSV2TIME0
    assert tnc.data_to_send() == NAK
    assert tnc.next_event() is None


def test_marked_handshake_character_is_noise() -> None:
    """A marked DLE 1 is no acknowledgement, a marked ENQ no request."""
    pc = SerialLink(LinkRole.CLIENT)
    pc.send(Frame("R_VR"), 0.0)
    pc.data_to_send()
    pc.receive_data(READY, 0.01)
    pc.data_to_send()
    pc.receive_data(RECEIVED, 0.02, [1])
    assert pc.next_event() is None
    pc.tick(0.02 + 3.0)  # no acknowledgement: EOT and the transmission again
    assert pc.data_to_send() == EOT + ENQ
    tnc = SerialLink(LinkRole.CONTROL)
    tnc.receive_data(ENQ, 0.0, [0])
    assert tnc.data_to_send() == b""


# -- equal telegrams in a row (docs/lsv2-serial.md) ------------------------------------------

S_FL1 = encode_serial_frame(Frame("S_FL", b"1 L X+1\x00"))
S_FL2 = encode_serial_frame(Frame("S_FL", b"2 L X+2\x00"))


def test_lost_dle1_then_an_answer_equal_to_the_last_one_confirms_the_block() -> None:
    """Download: the client's DLE 1 for block 2 is lost and it answers T_OK, like it answered
    block 1. That T_OK is new (the control framed block 2 since): block 2 is confirmed, not
    sent again and taken twice."""
    tnc = SerialLink(LinkRole.CONTROL)
    tnc.receive_data(ENQ, 0.0)
    tnc.data_to_send()
    tnc.receive_data(T_OK, 0.01)  # the answer to block 1
    assert tnc.data_to_send() == RECEIVED
    tnc.receive_data(EOT, 0.02)
    assert tnc.next_event() == TelegramReceived(Frame("T_OK"))
    tnc.send(Frame("S_FL", b"2 L X+2\x00"), 0.03)
    assert tnc.data_to_send() == ENQ
    tnc.receive_data(READY, 0.04)
    assert tnc.data_to_send() == S_FL2
    # the client's DLE 1 never arrives; after its LSV2TIME2 it sends its answer: ENQ, T_OK
    tnc.receive_data(ENQ, 1.1)
    assert tnc.data_to_send() == READY
    tnc.receive_data(T_OK, 1.2)
    assert tnc.data_to_send() == RECEIVED
    assert tnc.next_event() == TelegramSent(Frame("S_FL", b"2 L X+2\x00"), 1)
    assert tnc.next_event() == TelegramReceived(Frame("T_OK"))  # passed on: a new answer
    assert tnc.stats.implicit_acks == 1
    tnc.receive_data(EOT, 1.3)
    assert tnc.idle


def test_block_refused_after_yielding_waits_for_the_peer_before_repeating_ours() -> None:
    """We yielded with our T_OK unconfirmed and refused the control's block: the control
    repeats its block after LSV2TIME1; our T_OK is repeated only if it does not."""
    pc = SerialLink(LinkRole.CLIENT)
    pc.send(Frame("T_OK"), 0.0)
    pc.data_to_send()
    pc.receive_data(READY, 0.01)
    assert pc.data_to_send() == T_OK
    pc.receive_data(ENQ, 0.02)  # DLE 1 lost, the control moved on (or a spoilt NAK)
    assert pc.data_to_send() == READY
    pc.receive_data(S_FL1[:-1] + b"\x00", 0.03)  # its block, spoilt
    assert pc.data_to_send() == NAK
    pc.receive_data(EOT, 0.5)
    assert pc.data_to_send() == b""  # no ENQ of ours: the control's block comes first
    pc.receive_data(ENQ, 0.6)
    assert pc.data_to_send() == READY
    pc.receive_data(S_FL1, 0.7)
    assert pc.data_to_send() == RECEIVED
    assert pc.next_event() == TelegramSent(Frame("T_OK"), 1)  # confirmed by the new block
    assert pc.next_event() == TelegramReceived(Frame("S_FL", b"1 L X+1\x00"))


# -- a doubled ENQ (docs/lsv2-serial.md, "A doubled ENQ") -------------------------------------


def test_doubled_enq_is_answered_again_without_desynchronising() -> None:
    """The client's DLE 0 answer got lost, so it repeats ENQ: the control answers again and
    takes the block once."""
    tnc = SerialLink(LinkRole.CONTROL)
    tnc.receive_data(ENQ, 0.0)
    assert tnc.data_to_send() == READY  # lost on the way
    tnc.tick(1.0)  # LSV2TIME2: no block came, the line is idle again
    assert tnc.data_to_send() == b""
    tnc.receive_data(ENQ, 3.0)  # the client's LSV2TIME1 ran out: ENQ again
    assert tnc.data_to_send() == READY
    tnc.receive_data(LOGIN, 3.1)
    assert tnc.data_to_send() == RECEIVED
    tnc.receive_data(EOT, 3.2)
    assert tnc.next_event() == TelegramReceived(Frame("A_LG", b"INSPECT\x00"))
    assert tnc.next_event() is None


def test_doubled_enq_whose_first_answer_arrives_late_frames_once() -> None:
    """Both DLE 0 reach the client (the first one late): the block goes out once, the second
    DLE 0 is noise while the client waits for DLE 1."""
    pc = SerialLink(LinkRole.CLIENT)
    pc.send(Frame("A_LG", b"INSPECT\x00"), 0.0)
    pc.data_to_send()
    pc.tick(3.0)
    assert pc.data_to_send() == ENQ  # second try, no EOT: the block was never sent
    pc.receive_data(READY + READY, 3.01)
    assert pc.data_to_send() == LOGIN  # once
    pc.receive_data(RECEIVED, 3.1)
    assert pc.data_to_send() == EOT
    assert pc.next_event() == TelegramSent(Frame("A_LG", b"INSPECT\x00"), 2)


# -- the mirror case: a repeated answer must not confirm a block (docs/lsv2-serial.md) --------

S_FL3 = encode_serial_frame(Frame("S_FL", b"3 L X+3\x00"))


def _upload_until_block_2_framed(pc: SerialLink, *, eot_after_dle1: bool) -> None:
    """Block 1 goes through; its T_OK is taken (EOT after our DLE 1 or not); block 2 framed."""
    pc.send(Frame("S_FL", b"1 L X+1\x00"), 0.0)
    assert pc.data_to_send() == ENQ
    pc.receive_data(READY, 0.01)
    assert pc.data_to_send() == S_FL1
    pc.receive_data(RECEIVED, 0.05)
    assert pc.data_to_send() == EOT
    assert pc.next_event() == TelegramSent(Frame("S_FL", b"1 L X+1\x00"), 1)
    pc.receive_data(ENQ, 0.06)
    assert pc.data_to_send() == READY
    pc.receive_data(T_OK, 0.07)
    assert pc.data_to_send() == RECEIVED  # lost on the way when eot_after_dle1 is False
    assert pc.next_event() == TelegramReceived(Frame("T_OK"))
    pc.send(Frame("S_FL", b"2 L X+2\x00"), 0.07)
    if eot_after_dle1:
        pc.receive_data(EOT, 0.08)
        t = 0.09
    else:
        pc.tick(1.07)  # LSV2TIME2 without the control's EOT: did it have our DLE 1?
        t = 1.08
    assert pc.data_to_send() == ENQ
    pc.receive_data(READY, t)
    assert pc.data_to_send() == S_FL2


def test_repeated_answer_after_a_lost_dle1_never_confirms_the_next_block() -> None:
    """Our DLE 1 for the control's T_OK was lost (no EOT followed), so the control may repeat
    that T_OK. Block 2 goes out, its DLE 1 never comes, the control sends T_OK: its repeat (it
    never read block 2) or its answer to block 2, the line cannot tell. Taken as an answer,
    block 2 was missing from the file and the upload reported success (issue: 254 bytes short);
    now it is a typed link error and the T_OK is not passed on."""
    pc = SerialLink(LinkRole.CLIENT)
    _upload_until_block_2_framed(pc, eot_after_dle1=False)
    # block 2 spoilt at the control, its NAK lost; our retry ENQ lost too; the control's
    # LSV2TIME1 for its T_OK ran out: EOT, ENQ, the same T_OK again
    pc.tick(4.1)
    assert pc.data_to_send() == EOT + ENQ
    pc.receive_data(EOT + ENQ, 4.5)
    assert pc.data_to_send() == READY
    pc.receive_data(T_OK, 4.6)
    assert pc.data_to_send() == RECEIVED  # the control must stop repeating it either way
    event = pc.next_event()
    assert isinstance(event, LinkFailed)
    assert event.frame == Frame("S_FL", b"2 L X+2\x00")
    assert event.error.status is HostStatus.NO_QUITT
    assert "cannot tell whether it arrived" in str(event.error)
    assert pc.next_event() is None  # no T_OK: the upload must not go on to block 3
    assert pc.stats.ambiguous == 1
    pc.receive_data(EOT, 4.7)
    assert pc.idle


def test_answer_after_a_confirmed_one_still_confirms_the_block() -> None:
    """The single fault stays safe: the control had our DLE 1 for its T_OK (its EOT came at
    once), so it never repeats that T_OK; a T_OK after our unconfirmed block 2 is its answer."""
    pc = SerialLink(LinkRole.CLIENT)
    _upload_until_block_2_framed(pc, eot_after_dle1=True)
    pc.receive_data(ENQ, 1.2)  # block 2's DLE 1 lost; the control answers after LSV2TIME2
    assert pc.data_to_send() == READY
    pc.receive_data(T_OK, 1.3)
    assert pc.data_to_send() == RECEIVED
    assert pc.next_event() == TelegramSent(Frame("S_FL", b"2 L X+2\x00"), 1)
    assert pc.next_event() == TelegramReceived(Frame("T_OK"))
    assert pc.stats.ambiguous == 0


def test_late_eot_is_no_confirmation() -> None:
    """An EOT long after our DLE 1 is the control's LSV2TIME1 running out (it never had the
    DLE 1): the T_OK stays unconfirmed and a T_OK after block 2 stays ambiguous."""
    pc = SerialLink(LinkRole.CLIENT, timing=LinkTiming(time2=3.0))
    pc.send(Frame("T_OK"), 0.0)  # any telegram of ours, answered by the control's T_OK
    pc.data_to_send()
    pc.receive_data(READY, 0.01)
    pc.data_to_send()
    pc.receive_data(RECEIVED, 0.02)
    assert pc.data_to_send() == EOT
    pc.receive_data(ENQ, 0.03)
    pc.receive_data(T_OK, 0.04)
    assert pc.data_to_send() == READY + RECEIVED
    pc.receive_data(EOT, 2.9)  # 2.86 s after our DLE 1: the control gave up waiting for it
    pc.send(Frame("S_FL", b"3 L X+3\x00"), 2.9)
    assert pc.data_to_send() == ENQ
    pc.receive_data(READY, 2.91)
    assert pc.data_to_send() == S_FL3
    pc.receive_data(ENQ, 3.0)
    pc.receive_data(T_OK, 3.1)
    assert pc.next_event() == TelegramSent(Frame("T_OK"), 1)
    assert pc.next_event() == TelegramReceived(Frame("T_OK"))  # the first one
    event = pc.next_event()
    assert isinstance(event, LinkFailed), event
    assert pc.next_event() is None


def test_repeated_answer_after_a_refused_block_is_a_repeat_and_the_block_goes_again() -> None:
    """The sequence that lost a block through the cable: our DLE 1 for T_OK lost, block 2
    refused with NAK, our retry ENQ lost, and the control, waiting in vain for block 2 again,
    repeats its T_OK. Every frame of block 2 was refused, so the control does not hold it: the
    T_OK is its repeat (acknowledged, not passed on) and block 2 goes out again."""
    pc = SerialLink(LinkRole.CLIENT)
    _upload_until_block_2_framed(pc, eot_after_dle1=False)
    pc.receive_data(NAK, 1.12)
    assert pc.data_to_send() == EOT + ENQ  # that ENQ is lost
    pc.receive_data(ENQ, 4.12)  # the control's LSV2TIME1 ran out first
    assert pc.data_to_send() == READY
    pc.receive_data(T_OK, 4.13)
    assert pc.data_to_send() == RECEIVED
    assert pc.next_event() is None  # neither a confirmation of block 2 nor a second T_OK
    assert pc.stats.repeats_dropped == 1
    pc.receive_data(EOT, 4.14)
    assert pc.data_to_send() == ENQ  # block 2 again
    pc.receive_data(READY, 4.15)
    assert pc.data_to_send() == S_FL2
    pc.receive_data(RECEIVED, 4.2)
    assert pc.data_to_send() == EOT
    assert pc.next_event() == TelegramSent(Frame("S_FL", b"2 L X+2\x00"), 3)
