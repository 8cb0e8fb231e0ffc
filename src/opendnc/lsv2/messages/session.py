"""Telegrams of the session: transfer control, logins, versions, parameters, system commands."""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import ClassVar, Self

from opendnc.errors import RemoteProtocolError
from opendnc.lsv2.constants import error_text
from opendnc.lsv2.messages.base import (
    Message,
    _exact,
    _opt_cstr,
    _pack,
    register,
)
from opendnc.lsv2.payloads import (
    SystemParameters,
    cstr,
    join_cstrs,
    read_cstr,
    split_cstrs,
)

# --- transfer control -----------------------------------------------------------------------


@register
@dataclass(frozen=True, slots=True)
class Ok(Message):
    """``T_OK``: success, or "send the next block"."""

    MNEMONIC: ClassVar[str] = "T_OK"


@register
@dataclass(frozen=True, slots=True)
class FileDone(Message):
    """``T_FD``: end of a block sequence."""

    MNEMONIC: ClassVar[str] = "T_FD"


def _error_payload(code: int | None, error_type: int) -> bytes:
    return b"" if code is None else _pack(">BB", error_type, code)


def _error_fields(payload: bytes, name: str) -> tuple[int | None, int]:
    # Two bytes (type, code); an empty payload is tolerated as "type 1, no code".
    if not payload:
        return None, 1
    _exact(payload, 2, name)
    return payload[1], payload[0]


@register
@dataclass(frozen=True, slots=True)
class Refused(Message):
    """``T_ER``: the request failed with ``code`` (docs/lsv2.md#error-codes)."""

    MNEMONIC: ClassVar[str] = "T_ER"
    code: int | None
    error_type: int = 1

    @property
    def text(self) -> str:
        """Readable meaning of the code."""
        return error_text(self.code)

    def to_payload(self) -> bytes:
        return _error_payload(self.code, self.error_type)

    @classmethod
    def from_payload(cls, payload: bytes) -> Self:
        code, etype = _error_fields(payload, "T_ER")
        return cls(code, etype)


@register
@dataclass(frozen=True, slots=True)
class BlockDefect(Message):
    """``T_BD``: a block transfer was aborted (code 100-199), or a bare stop request."""

    MNEMONIC: ClassVar[str] = "T_BD"
    code: int | None = None
    error_type: int = 1

    @property
    def text(self) -> str:
        """Readable meaning of the code."""
        return error_text(self.code)

    def to_payload(self) -> bytes:
        return _error_payload(self.code, self.error_type)

    @classmethod
    def from_payload(cls, payload: bytes) -> Self:
        code, etype = _error_fields(payload, "T_BD")
        return cls(code, etype)


# --- access ---------------------------------------------------------------------------------


@register
@dataclass(frozen=True, slots=True)
class Login(Message):
    """``A_LG``: log in as ``login`` (optionally with a password)."""

    MNEMONIC: ClassVar[str] = "A_LG"
    login: str
    password: str | None = None

    def to_payload(self) -> bytes:
        return cstr(self.login) + _opt_cstr(self.password)

    @classmethod
    def from_payload(cls, payload: bytes) -> Self:
        if not payload:
            raise RemoteProtocolError("A_LG without a login name")
        login, off = read_cstr(payload, 0, what="login name")
        password = read_cstr(payload, off, what="password")[0] if off < len(payload) else None
        return cls(login, password)


@register
@dataclass(frozen=True, slots=True)
class Logout(Message):
    """``A_LO``: drop one login, or all of them when ``login`` is ``None``."""

    MNEMONIC: ClassVar[str] = "A_LO"
    login: str | None = None

    def to_payload(self) -> bytes:
        return _opt_cstr(self.login)

    @classmethod
    def from_payload(cls, payload: bytes) -> Self:
        return cls(read_cstr(payload, 0, what="login name")[0] if payload else None)


# --- versions, parameters, system information ----------------------------------------------


@register
@dataclass(frozen=True, slots=True)
class ReadVersion(Message):
    """``R_VR``: all version strings (``selector=None``) or one (docs/lsv2.md#versions)."""

    MNEMONIC: ClassVar[str] = "R_VR"
    selector: int | None = None

    def to_payload(self) -> bytes:
        return b"" if self.selector is None else _pack(">B", self.selector)

    @classmethod
    def from_payload(cls, payload: bytes) -> Self:
        if len(payload) > 1:
            raise RemoteProtocolError(f"R_VR selector must be 1 byte, got {len(payload)}")
        return cls(payload[0] if payload else None)


@register
@dataclass(frozen=True, slots=True)
class VersionReply(Message):
    """``S_VR``: NUL-terminated version strings."""

    MNEMONIC: ClassVar[str] = "S_VR"
    parts: tuple[str, ...]

    def to_payload(self) -> bytes:
        return join_cstrs(self.parts)

    @classmethod
    def from_payload(cls, payload: bytes) -> Self:
        return cls(split_cstrs(payload))


@register
@dataclass(frozen=True, slots=True)
class ReadParameters(Message):
    """``R_PR``: ask for the system parameters."""

    MNEMONIC: ClassVar[str] = "R_PR"


@register
@dataclass(frozen=True, slots=True)
class ParametersReply(Message):
    """``S_PR``: the system parameters (docs/lsv2.md#system-parameters)."""

    MNEMONIC: ClassVar[str] = "S_PR"
    params: SystemParameters

    def to_payload(self) -> bytes:
        return self.params.to_bytes()

    @classmethod
    def from_payload(cls, payload: bytes) -> Self:
        return cls(SystemParameters.from_bytes(payload))


@register
@dataclass(frozen=True, slots=True)
class ReadSystemInfo(Message):
    """``R_CI``: system information selector (docs/lsv2.md#system-information)."""

    MNEMONIC: ClassVar[str] = "R_CI"
    selector: int

    def to_payload(self) -> bytes:
        return _pack(">I", self.selector)

    @classmethod
    def from_payload(cls, payload: bytes) -> Self:
        _exact(payload, 4, "R_CI")
        return cls(int.from_bytes(payload, "big"))


@register
@dataclass(frozen=True, slots=True)
class SystemInfoReply(Message):
    """``S_CI``: ``u32`` value type (1 boolean, 2 number) and ``u32`` value."""

    MNEMONIC: ClassVar[str] = "S_CI"
    value_type: int
    value: int

    def to_payload(self) -> bytes:
        return _pack(">II", self.value_type, self.value)

    @classmethod
    def from_payload(cls, payload: bytes) -> Self:
        _exact(payload, 8, "S_CI")
        return cls(*struct.unpack(">II", payload))


@register
@dataclass(frozen=True, slots=True)
class SystemCommand(Message):
    """``C_CC``: sub-command (docs/lsv2.md#system-commands) with an optional string parameter."""

    MNEMONIC: ClassVar[str] = "C_CC"
    command: int
    parameter: str | None = None

    def to_payload(self) -> bytes:
        return _pack(">H", self.command) + _opt_cstr(self.parameter)

    @classmethod
    def from_payload(cls, payload: bytes) -> Self:
        if len(payload) < 2:
            raise RemoteProtocolError(f"C_CC needs a 2-byte sub-command, got {len(payload)}")
        (command,) = struct.unpack_from(">H", payload)
        param = read_cstr(payload, 2, what="C_CC parameter")[0] if len(payload) > 2 else None
        return cls(command, param)


@register
@dataclass(frozen=True, slots=True)
class CommandDone(Message):
    """``M_CC`` (unsolicited): a slow ``C_CC`` finished; ``value`` 100 = done."""

    MNEMONIC: ClassVar[str] = "M_CC"
    command: int
    value: int = 100
    extra: bytes = b""

    def to_payload(self) -> bytes:
        return _pack(">HH", self.command, self.value) + self.extra

    @classmethod
    def from_payload(cls, payload: bytes) -> Self:
        if len(payload) < 4:
            raise RemoteProtocolError(f"M_CC needs 4 bytes, got {len(payload)}")
        command, value = struct.unpack_from(">HH", payload)
        return cls(command, value, payload[4:])


@register
@dataclass(frozen=True, slots=True)
class ReadStatus(Message):
    """``R_ST``: read the 12-byte remote status."""

    MNEMONIC: ClassVar[str] = "R_ST"


def _blob12(payload: bytes, name: str) -> bytes:
    _exact(payload, 12, name)
    return payload


@register
@dataclass(frozen=True, slots=True)
class StatusReply(Message):
    """``S_ST``: 12-byte status blob (contents unknown)."""

    MNEMONIC: ClassVar[str] = "S_ST"
    status: bytes

    def to_payload(self) -> bytes:
        return _blob12(self.status, "S_ST")

    @classmethod
    def from_payload(cls, payload: bytes) -> Self:
        return cls(_blob12(payload, "S_ST"))


@register
@dataclass(frozen=True, slots=True)
class SetStatus(Message):
    """``C_ST``: write a 12-byte status blob."""

    MNEMONIC: ClassVar[str] = "C_ST"
    status: bytes

    def to_payload(self) -> bytes:
        return _blob12(self.status, "C_ST")

    @classmethod
    def from_payload(cls, payload: bytes) -> Self:
        return cls(_blob12(payload, "C_ST"))


@register
@dataclass(frozen=True, slots=True)
class ReadDateTime(Message):
    """``R_DT``: read the control's clock."""

    MNEMONIC: ClassVar[str] = "R_DT"


@register
@dataclass(frozen=True, slots=True)
class DateTimeReply(Message):
    """``S_DT``: ``u32`` seconds since 1970, then bytes of unknown meaning."""

    MNEMONIC: ClassVar[str] = "S_DT"
    timestamp: int
    extra: bytes = b""

    def to_payload(self) -> bytes:
        return _pack(">I", self.timestamp) + self.extra

    @classmethod
    def from_payload(cls, payload: bytes) -> Self:
        if len(payload) < 4:
            raise RemoteProtocolError(f"S_DT needs 4 bytes, got {len(payload)}")
        return cls(int.from_bytes(payload[:4], "big"), payload[4:])


@register
@dataclass(frozen=True, slots=True)
class SetDateTime(Message):
    """``C_DT``: set the clock (layout unknown; raw bytes)."""

    MNEMONIC: ClassVar[str] = "C_DT"
    data: bytes = b""

    def to_payload(self) -> bytes:
        return self.data

    @classmethod
    def from_payload(cls, payload: bytes) -> Self:
        return cls(payload)
