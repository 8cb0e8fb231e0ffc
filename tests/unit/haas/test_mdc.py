"""MDC codec: requests, framing for NGC and classic, typed replies, broadcast matching."""

from __future__ import annotations

import pytest

from opendnc.errors import LocalProtocolError, PeerClosed, RemoteProtocolError
from opendnc.haas import mdc


@pytest.mark.parametrize(
    ("request_", "wire"),
    [
        (mdc.Query(100), b"?Q100\r\n"),
        (mdc.Query(500), b"?Q500\r\n"),
        (mdc.MacroRead(5223), b"?Q600 5223\r\n"),
        (mdc.MacroWrite(10100, 1.5), b"?E10100 1.5\r\n"),
        (mdc.MacroWrite(100, -2.0), b"?E100 -2.0\r\n"),
    ],
)
def test_encode_and_parse_requests(request_: mdc.Request, wire: bytes) -> None:
    assert mdc.encode_request(request_) == wire
    assert mdc.parse_request(wire.decode().strip()) == request_


def test_encode_refuses_q600_as_plain_query() -> None:
    with pytest.raises(LocalProtocolError):
        mdc.encode_request(mdc.Query(600))


@pytest.mark.parametrize("line", ["?q100", "Q100", "?Q600", "?Q100 5", "?E100", "hello", "?Q1000"])
def test_unknown_requests(line: str) -> None:
    assert isinstance(mdc.parse_request(line), mdc.UnknownRequest)


def test_reply_framing_ngc_and_classic() -> None:
    payload = "SERIAL NUMBER, 1234567"
    assert mdc.frame_reply(payload, mdc.ControlType.NGC) == b">SERIAL NUMBER, 1234567\r\n"
    assert (
        mdc.frame_reply(payload, mdc.ControlType.CLASSIC) == b"\x02SERIAL NUMBER, 1234567\x17\r\n>"
    )


@pytest.mark.parametrize("control", list(mdc.ControlType))
def test_reply_framer_reads_both_framings_in_pieces(control: mdc.ControlType) -> None:
    wire = b"".join(mdc.frame_reply(p, control) for p in ["A, 1", "B, 2", "!"])
    framer = mdc.ReplyFramer()
    out = []
    for byte in wire:
        framer.feed(bytes([byte]))
        while (payload := framer.next_payload()) is not None:
            out.append(payload)
    assert out == ["A, 1", "B, 2", "!"]


def test_reply_framer_tolerates_double_prompt() -> None:
    framer = mdc.ReplyFramer()
    framer.feed(b">>MODEL, VF-2\r\n>")
    assert framer.next_payload() == "MODEL, VF-2"
    assert framer.next_payload() is None


# Example replies from Haas's NGC table (docs/haas.md#q-commands)
@pytest.mark.parametrize(
    ("payload", "expected"),
    [
        ("SERIAL NUMBER, 1234567", mdc.TextValue("SERIAL NUMBER", "1234567")),
        ("SOFTWARE VERSION, 100.17.000.2037", mdc.TextValue("SOFTWARE VERSION", "100.17.000.2037")),
        ("MODEL, CSMD-G2", mdc.TextValue("MODEL", "CSMD-G2")),
        ("MODE, ZERO", mdc.Mode("ZERO")),
        ("MODE, (MDI)", mdc.Mode("MDI", parenthesized=True)),
        ("TOOL CHANGES, 35", mdc.Count("TOOL CHANGES", 35)),
        ("USING TOOL, 4", mdc.Count("USING TOOL", 4)),
        ("P.O. TIME, 06282:17:13", mdc.Duration("P.O. TIME", 6282 * 3600 + 17 * 60 + 13)),
        ("C.S. TIME, 00098:18:29", mdc.Duration("C.S. TIME", 98 * 3600 + 18 * 60 + 29)),
        ("LAST CYCLE, 00000:00:13", mdc.Duration("LAST CYCLE", 13)),
        ("PREV CYCLE, 00000:00:01", mdc.Duration("PREV CYCLE", 1)),
        ("M30 #1, 380", mdc.Count("M30 #1", 380)),
        ("M30 #2, 380", mdc.Count("M30 #2", 380)),
        ("PROGRAM, MDI, IDLE, PARTS, 380", mdc.ProgramStatus("MDI", "IDLE", 380)),
        ("PROGRAM, O00123, IDLE, PARTS, 380", mdc.ProgramStatus("O00123", "IDLE", 380)),
        ("STATUS, BUSY", mdc.Busy()),
        ("STATUS BUSY", mdc.Busy()),
        ("MACRO, 0.0", mdc.MacroValue(0.0)),
        ("MACRO, 5223, -2.5310", mdc.MacroValue(-2.531)),
        ("!", mdc.WriteAccepted()),
        ("?", mdc.Refused("?")),
        ("UNKNOWN", mdc.Refused("UNKNOWN")),
        ("SPINDLE, 1, 2", mdc.OtherReply("SPINDLE", ("1", "2"))),
    ],
)
def test_parse_reply(payload: str, expected: mdc.Reply) -> None:
    reply = mdc.parse_reply(payload)
    assert reply == expected
    # every typed reply renders back to a payload that parses to the same value
    assert mdc.parse_reply(reply.to_payload()) == reply


@pytest.mark.parametrize(
    "payload",
    ["TOOL CHANGES, many", "P.O. TIME, 1:2", "MACRO, nan", "MACRO", "PROGRAM, MDI", "MODEL", ""],
)
def test_parse_reply_errors(payload: str) -> None:
    with pytest.raises(RemoteProtocolError):
        mdc.parse_reply(payload)


def test_format_number() -> None:
    assert mdc.format_number(0) == "0.0"
    assert mdc.format_number(-0.0) == "0.0"
    assert mdc.format_number(-2.531) == "-2.531"
    assert mdc.format_number(10) == "10.0"


def test_connection_skips_foreign_replies() -> None:
    conn = mdc.MdcConnection()
    conn.receive_data(b">MODEL, VF-2\r\n")  # someone else's answer, before our request
    assert conn.send(mdc.Query(100)) == b"?Q100\r\n"
    conn.receive_data(b">USING TOOL, 3\r\n>SERIAL NUMBER, 99\r\n")
    assert conn.next_event() == mdc.TextValue("SERIAL NUMBER", "99")
    assert list(conn.foreign) == [mdc.TextValue("MODEL", "VF-2"), mdc.Count("USING TOOL", 3)]


def test_connection_busy_answers_q500_and_refusal_answers_anything() -> None:
    conn = mdc.MdcConnection()
    conn.send(mdc.Query(500))
    conn.receive_data(b">STATUS, BUSY\r\n")
    assert conn.next_event() == mdc.Busy()
    conn.send(mdc.Query(999))
    conn.receive_data(b">?\r\n")
    assert conn.next_event() == mdc.Refused("?")


def test_connection_one_request_at_a_time_and_eof() -> None:
    conn = mdc.MdcConnection()
    conn.send(mdc.Query(100))
    with pytest.raises(LocalProtocolError):
        conn.send(mdc.Query(101))
    assert conn.next_event() is None
    conn.receive_data(b"")
    with pytest.raises(PeerClosed):
        conn.next_event()
