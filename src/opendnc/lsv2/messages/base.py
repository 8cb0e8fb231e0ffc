"""Message base class, codec registry and the ``decode`` / ``encode`` entry points."""

from __future__ import annotations

import struct
from collections.abc import Callable
from typing import ClassVar, Self, TypeVar

from opendnc.errors import InputError, RemoteProtocolError
from opendnc.lsv2.framing import Frame
from opendnc.lsv2.payloads import ENCODING, cstr


class Message:
    """Base of all telegrams. ``MNEMONIC`` is the four-character telegram name."""

    __slots__ = ()
    MNEMONIC: ClassVar[str] = ""
    MNEMONIC_BYTES: ClassVar[bytes] = b""

    @property
    def mnemonic(self) -> str:
        """The telegram name."""
        return self.MNEMONIC

    def to_payload(self) -> bytes:
        """The payload bytes (empty by default)."""
        return b""

    @classmethod
    def from_payload(cls, payload: bytes) -> Self:
        """Decode a payload; the default accepts only an empty one."""
        if payload:
            raise RemoteProtocolError(f"{cls.MNEMONIC} carries no payload, got {len(payload)}")
        return cls()


_M = TypeVar("_M", bound=type[Message])
_Decoder = Callable[[bytes], Message]
REGISTRY: dict[str, _Decoder] = {}
"""Telegram name -> payload decoder."""


def register(cls: _M) -> _M:
    """Class decorator: enter ``cls`` into the registry under its ``MNEMONIC``."""
    cls.MNEMONIC_BYTES = cls.MNEMONIC.encode("ascii")
    REGISTRY[cls.MNEMONIC] = cls.from_payload
    return cls


def _exact(payload: bytes, size: int, name: str) -> None:
    if len(payload) != size:
        raise RemoteProtocolError(f"{name} payload must be {size} bytes, got {len(payload)}")


def _pack(fmt: str, *values: object) -> bytes:
    try:
        return struct.pack(fmt, *values)
    except struct.error as exc:
        raise InputError(f"value out of range for the wire: {exc}") from exc


def _opt_cstr(text: str | None) -> bytes:
    return b"" if text is None else cstr(text)


# --- codec entry points ---------------------------------------------------------------------


def decode(frame: Frame) -> Message:
    """Typed message of ``frame``; :class:`RemoteProtocolError` if unknown or malformed."""
    decoder = REGISTRY.get(frame.mnemonic)
    if decoder is None:
        raise RemoteProtocolError(f"unknown telegram {frame.mnemonic!r}")
    try:
        return decoder(frame.payload)
    except RemoteProtocolError as exc:
        raise RemoteProtocolError(f"malformed {frame.mnemonic}: {exc}") from exc
    except (struct.error, UnicodeDecodeError, ValueError, IndexError) as exc:
        # Layout checks above should catch everything; this keeps the promise that wire
        # data only ever produces RemoteProtocolError.
        raise RemoteProtocolError(f"malformed {frame.mnemonic}: {exc}") from exc


def encode(message: Message) -> Frame:
    """The frame of ``message``."""
    return Frame(message.mnemonic, message.to_payload())


def text_of(data: bytes) -> str:
    """Decode wire text (Latin-1)."""
    return data.decode(ENCODING)
