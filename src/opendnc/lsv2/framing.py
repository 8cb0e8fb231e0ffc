"""Cutting LSV2 byte streams into frames, for TCP and for RS-232.

A :class:`Frame` is a telegram name (four ASCII characters) plus its raw payload; turning it
into a typed message is the codec's job (:mod:`opendnc.lsv2.messages`).

TCP (docs/lsv2.md#tcp-framing)::

    u32 payload length | 4 ASCII name | payload

RS-232 (docs/lsv2.md#serial-lsv2)::

    DLE STX | name + payload, every DLE doubled | DLE ETX | BCC

with BCC = XOR of the *unstuffed* name + payload bytes, XOR ETX. Between frames the serial link
carries single control characters (ENQ, EOT, NAK, DLE '0', DLE '1'), which
:class:`SerialFramer` returns as :class:`SerialControl` items.

Both framers follow the same ``feed()`` / ``next_frame()`` shape: they never block, return
``None`` when more bytes are needed and raise :class:`~opendnc.errors.RemoteProtocolError`
(or :class:`~opendnc.errors.ChecksumError`) for bytes that cannot be a valid frame.
"""

from __future__ import annotations

import enum
import struct
from dataclasses import dataclass
from functools import reduce
from operator import xor

from opendnc.errors import ChecksumError, LocalProtocolError, RemoteProtocolError

__all__ = [
    "DLE",
    "ENQ",
    "EOT",
    "ETX",
    "NAK",
    "STX",
    "Frame",
    "SerialControl",
    "SerialFramer",
    "TelegramFramer",
    "bcc",
    "encode_serial_frame",
]

HEADER = struct.Struct(">I4s")
HEADER_SIZE = HEADER.size
DEFAULT_MAX_PAYLOAD = 65536
"""Largest payload a framer accepts unless told otherwise; real telegrams stay ≤ 4096 bytes."""


_NAMES: dict[bytes, str] = {}


def _check_name(raw: bytes) -> str:
    # Telegram names are four printable ASCII characters such as b"T_OK"; anything else means
    # we lost sync with the stream, and guessing further would only produce garbage.
    name = _NAMES.get(raw)
    if name is not None:
        return name  # fast path: names seen before (a transfer repeats S_FL / T_OK)
    if len(raw) != 4 or not all(0x21 <= b <= 0x7E for b in raw):
        raise RemoteProtocolError(f"bad telegram name {raw!r}")
    name = raw.decode("ascii")
    if len(_NAMES) < 1024:
        _NAMES[bytes(raw)] = name
    return name


@dataclass(frozen=True, slots=True)
class Frame:
    """One telegram: its four-character name and raw payload."""

    mnemonic: str
    payload: bytes = b""

    def __post_init__(self) -> None:
        if len(self.mnemonic) != 4 or not self.mnemonic.isascii():
            raise LocalProtocolError(
                f"telegram name must be 4 ASCII characters, got {self.mnemonic!r}"
            )

    @property
    def body(self) -> bytes:
        """Name and payload as one byte string (what the serial envelope carries)."""
        return self.mnemonic.encode("ascii") + self.payload


class TelegramFramer:
    """LSV2-over-TCP framer: 8-byte header (u32 length, 4-byte name), then the payload."""

    def __init__(self, max_payload: int = DEFAULT_MAX_PAYLOAD) -> None:
        self._buf = bytearray()
        # A read usually holds exactly one telegram. Such a chunk is kept as it came, so its
        # payload is cut out with one copy instead of going through the bytearray (append,
        # slice, bytes(), delete): at thousands of 4 KiB blocks a second that is measurable.
        self._chunk = b""
        self.max_payload = max_payload

    def feed(self, data: bytes) -> None:
        """Append received bytes."""
        if not self._buf and not self._chunk:
            self._chunk = bytes(data)
            return
        self._spill()
        self._buf += data

    def _spill(self) -> None:
        if self._chunk:
            self._buf += self._chunk
            self._chunk = b""

    @property
    def buffered(self) -> int:
        """Number of bytes received but not yet returned as frames."""
        return len(self._buf) + len(self._chunk)

    def next_frame(self) -> Frame | None:
        """Return the next complete frame, or ``None`` if more bytes are needed.

        The frame's bytes are consumed before its name is checked, so after an error the
        framer continues with the following telegram.
        """
        chunk = self._chunk
        if chunk:
            if len(chunk) >= HEADER_SIZE:
                length, raw = HEADER.unpack_from(chunk)
                end = HEADER_SIZE + length
                if end == len(chunk) and length <= self.max_payload:
                    self._chunk = b""
                    return Frame(_check_name(raw), chunk[HEADER_SIZE:])
            self._spill()  # a partial or several telegrams: take the general path
        buf = self._buf
        if len(buf) < HEADER_SIZE:
            return None
        length, raw = HEADER.unpack_from(buf)
        if length > self.max_payload:
            raise RemoteProtocolError(
                f"telegram announces {length} payload bytes, limit is {self.max_payload}"
            )
        end = HEADER_SIZE + length
        if len(buf) < end:
            return None
        payload = bytes(buf[HEADER_SIZE:end])
        del buf[:end]
        return Frame(_check_name(raw), payload)

    @staticmethod
    def encode(frame: Frame) -> bytes:
        """Wire bytes of ``frame`` (header + payload in one string, for a single write)."""
        return HEADER.pack(len(frame.payload), frame.mnemonic.encode("ascii")) + frame.payload


# --- RS-232 --------------------------------------------------------------------------------

STX = 0x02
ETX = 0x03
EOT = 0x04
ENQ = 0x05
ACK = 0x06
DLE = 0x10
NAK = 0x15

_DLE_B = b"\x10"
_DLE_DLE = b"\x10\x10"


class SerialControl(enum.Enum):
    """Link-control signals of serial LSV2 (docs/lsv2.md#serial-control-characters)."""

    ENQ = "ENQ"  # request to send
    EOT = "EOT"  # end of transmission
    NAK = "NAK"  # block bad / not ready
    ACK = "ACK"  # defined, unused by LSV2
    READY = "DLE 0"  # ready to receive (answer to ENQ)
    RECEIVED = "DLE 1"  # telegram received correctly

    def encode(self) -> bytes:
        """Wire bytes of this signal."""
        return _CONTROL_BYTES[self]


_CONTROL_BYTES: dict[SerialControl, bytes] = {
    SerialControl.ENQ: bytes([ENQ]),
    SerialControl.EOT: bytes([EOT]),
    SerialControl.NAK: bytes([NAK]),
    SerialControl.ACK: bytes([ACK]),
    SerialControl.READY: b"\x10\x30",
    SerialControl.RECEIVED: b"\x10\x31",
}
_SINGLE: dict[int, SerialControl] = {
    ENQ: SerialControl.ENQ,
    EOT: SerialControl.EOT,
    NAK: SerialControl.NAK,
    ACK: SerialControl.ACK,
}


def bcc(body: bytes) -> int:
    """Block check character of an unstuffed frame body: XOR of all bytes, XOR ETX."""
    if len(body) < 16:
        return reduce(xor, body, ETX)
    # Fold the body as one big integer: XOR its halves until one byte is left. Zero padding
    # to a power-of-two length changes nothing, and it avoids a Python loop per byte.
    width = 1 << (len(body) - 1).bit_length()
    value = int.from_bytes(body.ljust(width, b"\0"), "little")
    bits = width * 8
    while bits > 8:
        bits //= 2
        value = (value >> bits) ^ (value & ((1 << bits) - 1))
    return value ^ ETX


def encode_serial_frame(frame: Frame | bytes) -> bytes:
    """Serial envelope of ``frame`` (or of a raw body): DLE STX, stuffed body, DLE ETX, BCC."""
    body = frame.body if isinstance(frame, Frame) else frame
    return b"\x10\x02" + body.replace(_DLE_B, _DLE_DLE) + b"\x10\x03" + bytes([bcc(body)])


class SerialFramer:
    """Serial LSV2 framer: yields :class:`Frame` for each DLE STX ... DLE ETX BCC block and
    :class:`SerialControl` for each link-control signal, in arrival order."""

    def __init__(self, max_body: int = DEFAULT_MAX_PAYLOAD) -> None:
        self._buf = bytearray()
        self.max_body = max_body

    def feed(self, data: bytes) -> None:
        """Append received bytes."""
        self._buf += data

    @property
    def buffered(self) -> int:
        """Number of bytes not yet returned."""
        return len(self._buf)

    def clear(self) -> None:
        """Drop buffered bytes (after a NAK the sender repeats the whole transmission)."""
        self._buf.clear()

    def next_frame(self) -> Frame | SerialControl | None:
        """Return the next frame or control signal, ``None`` if more bytes are needed."""
        buf = self._buf
        if not buf:
            return None
        first = buf[0]
        control = _SINGLE.get(first)
        if control is not None:
            del buf[:1]
            return control
        if first != DLE:
            del buf[:1]
            raise RemoteProtocolError(f"unexpected byte 0x{first:02X} outside a serial telegram")
        if len(buf) < 2:
            return None
        second = buf[1]
        if second == 0x30:
            del buf[:2]
            return SerialControl.READY
        if second == 0x31:
            del buf[:2]
            return SerialControl.RECEIVED
        if second != STX:
            del buf[:2]
            raise RemoteProtocolError(f"unexpected sequence DLE 0x{second:02X} on serial link")
        return self._frame()

    def _frame(self) -> Frame | None:
        buf = self._buf
        pos = 2
        while True:
            i = buf.find(_DLE_B, pos)
            if i < 0 or i + 1 >= len(buf):
                if len(buf) - 2 > 2 * self.max_body + 2:
                    self._buf.clear()
                    raise RemoteProtocolError(
                        f"serial telegram longer than {self.max_body} bytes without DLE ETX"
                    )
                return None
            nxt = buf[i + 1]
            if nxt == DLE:
                pos = i + 2
                continue
            if nxt != ETX:
                del buf[: i + 2]
                raise RemoteProtocolError(
                    f"unexpected sequence DLE 0x{nxt:02X} inside a serial telegram"
                )
            if i + 2 >= len(buf):
                return None  # the BCC byte has not arrived yet
            check = buf[i + 2]
            body = bytes(buf[2:i]).replace(_DLE_DLE, _DLE_B)
            del buf[: i + 3]
            if len(body) > self.max_body:
                raise RemoteProtocolError(
                    f"serial telegram of {len(body)} bytes, limit is {self.max_body}"
                )
            expected = bcc(body)
            if check != expected:
                raise ChecksumError(f"serial telegram BCC 0x{check:02X}, computed 0x{expected:02X}")
            if len(body) < 4:
                raise RemoteProtocolError(f"serial telegram of {len(body)} bytes has no name")
            return Frame(_check_name(body[:4]), body[4:])
