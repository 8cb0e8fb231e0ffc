"""Block encoding, decoding and the two checks."""

from __future__ import annotations

import pytest

from opendnc.errors import ChecksumError, LocalProtocolError, RemoteProtocolError
from opendnc.xmodem.framing import (
    SOH,
    STX,
    checksum,
    crc16,
    decode_block,
    encode_block,
    frame_length,
)


def test_crc16_xmodem_check_value() -> None:
    # the catalogue check value of CRC-16/XMODEM
    assert crc16(b"123456789") == 0x31C3
    assert crc16(b"") == 0


def test_checksum_is_sum_mod_256() -> None:
    assert checksum(b"\xff\x02") == 0x01
    assert checksum(bytes(range(256))) == (255 * 256 // 2) % 256


@pytest.mark.parametrize(("crc", "large"), [(False, False), (True, False), (True, True)])
def test_round_trip_and_padding(crc: bool, large: bool) -> None:
    raw = encode_block(300, b"abc", crc=crc, large=large)  # 300 wraps to 44
    assert raw[0] == (STX if large else SOH)
    assert raw[1] == 44
    assert raw[2] == 255 - 44
    assert len(raw) == frame_length(raw[0], crc)
    block = decode_block(raw, crc=crc)
    assert block.seq == 44
    assert block.data == b"abc" + b"\x1a" * ((1024 if large else 128) - 3)


def test_block_number_255_then_0() -> None:
    assert encode_block(255, b"", crc=False)[1:3] == b"\xff\x00"
    assert encode_block(256, b"", crc=False)[1:3] == b"\x00\xff"


def test_crc_is_sent_high_byte_first() -> None:
    raw = encode_block(1, b"123456789", crc=True)
    assert raw[-2:] == crc16(b"123456789" + b"\x1a" * 119).to_bytes(2, "big")


@pytest.mark.parametrize("crc", [False, True])
def test_every_single_byte_corruption_is_detected(crc: bool) -> None:
    raw = bytearray(encode_block(7, bytes(range(128)), crc=crc))
    for i in range(len(raw)):
        bad = bytearray(raw)
        bad[i] ^= 0x20
        with pytest.raises(RemoteProtocolError):
            decode_block(bad, crc=crc)


def test_decode_errors_are_typed_and_named() -> None:
    raw = encode_block(1, b"x", crc=False)
    with pytest.raises(ChecksumError, match="checksum"):
        decode_block(raw[:-1] + bytes([raw[-1] ^ 1]), crc=False)
    with pytest.raises(RemoteProtocolError, match="complement"):
        decode_block(raw[:2] + b"\x00" + raw[3:], crc=False)
    with pytest.raises(RemoteProtocolError, match="expected 133"):
        decode_block(raw, crc=True)
    with pytest.raises(RemoteProtocolError, match="SOH or STX"):
        decode_block(b"\x03" + raw[1:], crc=False)
    with pytest.raises(RemoteProtocolError, match="shorter"):
        decode_block(b"\x01", crc=False)
    with pytest.raises(LocalProtocolError, match="do not fit"):
        encode_block(1, b"x" * 129, crc=False)


def test_haas_eob_folding_is_opt_in() -> None:
    # the control sums CR LF as a single LF (reported by OpenDNC, docs/xmodem.md#haas-dialect);
    # opt-in tolerance
    wire = b"G00X1.\r\nM30\r\n"
    data = wire + b"\x1a" * (128 - len(wire))
    folded_sum = checksum(data.replace(b"\r\n", b"\n"))
    raw = bytes((SOH, 1, 254)) + data + bytes((folded_sum,))
    with pytest.raises(ChecksumError):
        decode_block(raw, crc=False)
    assert decode_block(raw, crc=False, fold_eob=True).data == data
