"""XModem wire format: control bytes, block checks, block encoding and decoding.

A block is ``SOH|STX, seq, 255 - seq, data[128|1024], check`` where the check is either the
8-bit arithmetic sum of the data (original XModem, the only variant a Haas speaks) or the
CRC-16/XMODEM of the data, sent high byte first. Nothing here keeps state; the sender and
receiver engines build on these functions.
"""

from __future__ import annotations

import binascii
import enum
import zlib
from dataclasses import dataclass

from opendnc.errors import ChecksumError, LocalProtocolError, RemoteProtocolError

SOH = 0x01  # start of a 128-byte block
STX = 0x02  # start of a 1024-byte block (XModem-1K)
EOT = 0x04  # end of transmission
ACK = 0x06
NAK = 0x15  # "send again", and the start request for checksum mode
CAN = 0x18  # two in a row cancel the session
SUB = 0x1A  # padding of the last block (CP/M end-of-file)
CRC_REQUEST = 0x43  # 'C': the start request for CRC-16 mode

SMALL = 128
LARGE = 1024
HEADER = 3
CANCEL_BYTES = bytes((CAN, CAN, CAN))

_SUB_SMALL = bytes((SUB,)) * SMALL
_SUB_LARGE = bytes((SUB,)) * LARGE
_BYTE = tuple(bytes((i,)) for i in range(256))
# the three header bytes of every block number, prebuilt (encode_block runs once per block)
_HEAD_SMALL = tuple(bytes((SOH, i, 0xFF - i)) for i in range(256))
_HEAD_LARGE = tuple(bytes((STX, i, 0xFF - i)) for i in range(256))


class Mode(enum.Enum):
    """The three XModem variants, named as on the command line."""

    CHECKSUM = "checksum"  # 128-byte blocks, 8-bit sum, started by NAK
    CRC = "crc"  # 128-byte blocks, CRC-16, started by 'C'
    ONE_K = "1k"  # 1024-byte blocks where they pay off, CRC-16, started by 'C'

    @property
    def uses_crc(self) -> bool:
        """True when a receiver in this mode asks for CRC-16 (with a 'C')."""
        return self is not Mode.CHECKSUM


def checksum(data: bytes | bytearray | memoryview) -> int:
    """The original XModem check: the sum of the data bytes modulo 256."""
    if len(data) <= 256:
        # Adler-32's low half is 1 + the byte sum mod 65521; up to 256 bytes the sum stays
        # below 65521, so it is exact, and zlib computes it in C far faster than sum()
        return (zlib.adler32(data) - 1) & 0xFF
    return sum(data) & 0xFF


def crc16(data: bytes | bytearray | memoryview) -> int:
    """CRC-16/XMODEM (polynomial 0x1021, initial value 0, no reflection)."""
    return binascii.crc_hqx(data, 0)


def check_size(crc: bool) -> int:
    """Bytes of the check field: 2 for CRC-16, 1 for the sum."""
    return 2 if crc else 1


def block_size(start: int) -> int:
    """Data bytes announced by a start byte (SOH or STX)."""
    return LARGE if start == STX else SMALL


def encode_block(seq: int, data: bytes | memoryview, *, crc: bool, large: bool = False) -> bytes:
    """Encode one block; ``data`` shorter than the block is padded with SUB.

    ``large`` selects a 1024-byte STX block, otherwise a 128-byte SOH block.
    """
    size = LARGE if large else SMALL
    if len(data) > size:
        raise LocalProtocolError(f"{len(data)} bytes do not fit a {size}-byte block")
    seq &= 0xFF
    payload = bytes(data)
    if len(payload) < size:
        payload += (_SUB_LARGE if large else _SUB_SMALL)[: size - len(payload)]
    # one join instead of chained concatenations: this runs once per block on the hot path
    check = binascii.crc_hqx(payload, 0).to_bytes(2, "big") if crc else _BYTE[checksum(payload)]
    return b"".join(((_HEAD_LARGE if large else _HEAD_SMALL)[seq], payload, check))


@dataclass(frozen=True, slots=True)
class Block:
    """A decoded block: its sequence number (0..255) and its 128 or 1024 data bytes."""

    seq: int
    data: bytes


def frame_length(start: int, crc: bool) -> int:
    """Total length of a block beginning with ``start`` (header + data + check)."""
    return HEADER + block_size(start) + check_size(crc)


def decode_block(
    frame: bytes | bytearray | memoryview, *, crc: bool, fold_eob: bool = False
) -> Block:
    """Decode one complete block.

    Raises :class:`RemoteProtocolError` for a bad start byte, length or sequence complement
    and :class:`ChecksumError` when the check does not match. ``fold_eob`` accepts an 8-bit
    sum that only matches after CR LF and lone CR are folded to LF (a Haas reportedly sums
    its end-of-block as one LF whatever setting 25 puts on the wire; opt-in only).
    """
    seq, data = decode_frame(frame, crc=crc, fold_eob=fold_eob)
    return Block(seq, data)


def decode_frame(
    frame: bytes | bytearray | memoryview, *, crc: bool, fold_eob: bool = False
) -> tuple[int, bytes]:
    """:func:`decode_block` without the :class:`Block` wrapper: ``(seq, data)``.

    The receiver's per-block path; same checks and errors as :func:`decode_block`.
    """
    size = len(frame)
    if size < HEADER:
        raise RemoteProtocolError(f"block of {size} bytes is shorter than its header")
    start, seq, inverse = frame[0], frame[1], frame[2]
    if start == SOH:
        end = HEADER + SMALL
    elif start == STX:
        end = HEADER + LARGE
    else:
        raise RemoteProtocolError(f"block starts with 0x{start:02X}, expected SOH or STX")
    expected = end + (2 if crc else 1)
    if size != expected:
        raise RemoteProtocolError(f"block of {size} bytes, expected {expected}")
    if seq + inverse != 0xFF:
        raise RemoteProtocolError(
            f"block number 0x{seq:02X} and complement 0x{inverse:02X} disagree"
        )
    data = bytes(frame[HEADER:end])
    if crc:
        got = (frame[end] << 8) | frame[end + 1]
        want = binascii.crc_hqx(data, 0)
    else:
        got = frame[end]
        want = checksum(data)
        if got != want and fold_eob:
            folded = data.replace(b"\r\n", b"\n").replace(b"\r", b"\n")
            if checksum(folded) == got:
                want = got
    if got != want:
        kind, width = ("CRC", 4) if crc else ("checksum", 2)
        raise ChecksumError(f"block {seq}: {kind} 0x{got:0{width}X}, computed 0x{want:0{width}X}")
    return seq, data
