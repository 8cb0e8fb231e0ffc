"""TCP framer and RS-232 frame codec: golden vectors and error handling."""

from __future__ import annotations

import pytest

from opendnc.errors import ChecksumError, RemoteProtocolError
from opendnc.lsv2.framing import (
    Frame,
    SerialControl,
    SerialFramer,
    TelegramFramer,
    bcc,
    encode_serial_frame,
)
from tests.unit.lsv2.samples import S_PR_GOLDEN, TNC320_S_VR_PAYLOAD

A_LG_INSPECT = bytes.fromhex("00000008415F4C47494E535045435400")
T_OK = bytes.fromhex("00000000545F4F4B")


def test_golden_login_and_ok_bytes() -> None:
    assert TelegramFramer.encode(Frame("A_LG", b"INSPECT\0")) == A_LG_INSPECT
    assert TelegramFramer.encode(Frame("T_OK")) == T_OK
    framer = TelegramFramer()
    framer.feed(A_LG_INSPECT + T_OK)
    assert framer.next_frame() == Frame("A_LG", b"INSPECT\0")
    assert framer.next_frame() == Frame("T_OK")
    assert framer.next_frame() is None


def test_header_split_byte_by_byte() -> None:
    framer = TelegramFramer()
    wire = A_LG_INSPECT
    for b in wire[:-1]:
        framer.feed(bytes([b]))
        assert framer.next_frame() is None
    framer.feed(wire[-1:])
    assert framer.next_frame() == Frame("A_LG", b"INSPECT\0")
    assert framer.buffered == 0


def test_length_limit() -> None:
    framer = TelegramFramer(max_payload=100)
    framer.feed(b"\x00\x00\x00\x65S_FL")
    with pytest.raises(RemoteProtocolError, match="limit is 100"):
        framer.next_frame()


def test_bad_name_is_consumed_and_named() -> None:
    framer = TelegramFramer()
    framer.feed(b"\x00\x00\x00\x01\x00\xff\x01\x02x" + T_OK)
    with pytest.raises(RemoteProtocolError, match="bad telegram name"):
        framer.next_frame()
    assert framer.next_frame() == Frame("T_OK")


@pytest.mark.parametrize(
    ("body", "expected"),
    [
        (b"A_LGINSPECT\0", 0x40),
        (b"T_OK", 0x0C),
        (b"R_VR", 0x0A),
        (b"R_PR", 0x0C),
        (b"S_VR" + TNC320_S_VR_PAYLOAD, 0x71),
        (b"TNC 425", 0x49),
        (b"S_PR" + S_PR_GOLDEN, 0x44),
    ],
)
def test_bcc_golden_vectors(body: bytes, expected: int) -> None:
    assert bcc(body) == expected


def test_serial_capture_bytes() -> None:
    # docs/captures/lsv2-serial-tnc320.txt: >....0x10 0x02 A_LG INSPECT 0x00 0x10 0x03 0x40
    assert encode_serial_frame(Frame("A_LG", b"INSPECT\0")) == (
        b"\x10\x02A_LGINSPECT\x00\x10\x03\x40"
    )
    assert encode_serial_frame(Frame("T_OK")) == b"\x10\x02T_OK\x10\x03\x0c"


def test_serial_stuffing_uses_unstuffed_bcc() -> None:
    frame = Frame("S_PR", S_PR_GOLDEN)
    wire = encode_serial_frame(frame)
    assert S_PR_GOLDEN.count(0x10) == 1
    assert wire.count(b"\x10\x10") == 1
    assert wire[-1] == 0x44
    framer = SerialFramer()
    framer.feed(wire)
    assert framer.next_frame() == frame


def test_serial_exchange_tokens() -> None:
    framer = SerialFramer()
    framer.feed(b"\x05\x10\x30" + encode_serial_frame(Frame("T_OK")) + b"\x10\x31\x04\x15")
    items = []
    while (item := framer.next_frame()) is not None:
        items.append(item)
    assert items == [
        SerialControl.ENQ,
        SerialControl.READY,
        Frame("T_OK"),
        SerialControl.RECEIVED,
        SerialControl.EOT,
        SerialControl.NAK,
    ]
    assert SerialControl.READY.encode() == b"\x10\x30"


def test_serial_bad_bcc() -> None:
    wire = bytearray(encode_serial_frame(Frame("R_VR")))
    wire[-1] ^= 0xFF
    framer = SerialFramer()
    framer.feed(bytes(wire) + b"\x04")
    with pytest.raises(ChecksumError):
        framer.next_frame()
    assert framer.next_frame() is SerialControl.EOT


@pytest.mark.parametrize(
    "wire",
    [b"\x41", b"\x10\x41", b"\x10\x02T_OK\x10\x41", b"\x10\x02T_\x10\x03" + bytes([bcc(b"T_")])],
)
def test_serial_garbage(wire: bytes) -> None:
    framer = SerialFramer()
    framer.feed(wire)
    with pytest.raises(RemoteProtocolError):
        framer.next_frame()


def test_serial_unterminated_limit() -> None:
    framer = SerialFramer(max_body=10)
    framer.feed(b"\x10\x02" + b"A" * 40)
    with pytest.raises(RemoteProtocolError, match="without DLE ETX"):
        framer.next_frame()


def test_serial_incomplete_waits() -> None:
    wire = encode_serial_frame(Frame("T_OK"))
    framer = SerialFramer()
    for i in range(len(wire) - 1):
        framer.feed(wire[i : i + 1])
        assert framer.next_frame() is None
    framer.feed(wire[-1:])
    assert framer.next_frame() == Frame("T_OK")
