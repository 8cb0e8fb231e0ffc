"""Machine telegrams: PLC memory, machine parameters, data paths, run-time info, keys, scope."""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import ClassVar, Self

from opendnc.errors import InputError, RemoteProtocolError
from opendnc.lsv2.constants import DataType
from opendnc.lsv2.messages.base import (
    REGISTRY,
    Message,
    _Decoder,
    _exact,
    _pack,
    register,
)
from opendnc.lsv2.payloads import (
    ScopeChannel,
    ScopeSamples,
    ScopeSignal,
    ScopeSignalInfo,
    cstr,
    read_cstr,
)
from opendnc.lsv2.runinfo import RunInfoValue, decode_run_info

# --- PLC, machine parameters, data paths, run-time info -------------------------------------


@register
@dataclass(frozen=True, slots=True)
class ReadMemory(Message):
    """``R_MB``: read ``count`` (1-255) bytes of PLC memory at ``address``."""

    MNEMONIC: ClassVar[str] = "R_MB"
    address: int
    count: int

    def to_payload(self) -> bytes:
        if not 1 <= self.count <= 255:
            raise InputError(f"R_MB reads 1-255 bytes, not {self.count}")
        return _pack(">IB", self.address, self.count)

    @classmethod
    def from_payload(cls, payload: bytes) -> Self:
        _exact(payload, 5, "R_MB")
        address, count = struct.unpack(">IB", payload)
        if count == 0:
            raise RemoteProtocolError("R_MB asks for 0 bytes")
        return cls(address, count)


@register
@dataclass(frozen=True, slots=True)
class MemoryReply(Message):
    """``S_MB``: raw PLC memory bytes (multi-byte values little-endian)."""

    MNEMONIC: ClassVar[str] = "S_MB"
    data: bytes

    def to_payload(self) -> bytes:
        return self.data

    @classmethod
    def from_payload(cls, payload: bytes) -> Self:
        return cls(payload)


@register
@dataclass(frozen=True, slots=True)
class ReadMachineParameter(Message):
    """``R_MC``: read a machine parameter by name / number."""

    MNEMONIC: ClassVar[str] = "R_MC"
    name: str

    def to_payload(self) -> bytes:
        return cstr(self.name)

    @classmethod
    def from_payload(cls, payload: bytes) -> Self:
        if not payload:
            raise RemoteProtocolError("R_MC without a parameter name")
        return cls(read_cstr(payload, 0, what="parameter name")[0])


@register
@dataclass(frozen=True, slots=True)
class MachineParameterReply(Message):
    """``S_MC``: a machine parameter value as text."""

    MNEMONIC: ClassVar[str] = "S_MC"
    value: str

    def to_payload(self) -> bytes:
        return cstr(self.value)

    @classmethod
    def from_payload(cls, payload: bytes) -> Self:
        return cls(read_cstr(payload, 0, what="parameter value")[0])


@register
@dataclass(frozen=True, slots=True)
class WriteMachineParameter(Message):
    """``C_MC``: write a machine parameter (flags 0 permanent, 1 until restart)."""

    MNEMONIC: ClassVar[str] = "C_MC"
    name: str
    value: str
    flags: int = 0

    def to_payload(self) -> bytes:
        return _pack(">I", self.flags) + cstr(self.name) + cstr(self.value)

    @classmethod
    def from_payload(cls, payload: bytes) -> Self:
        if len(payload) < 5:
            raise RemoteProtocolError(f"C_MC needs flags and a name, got {len(payload)} bytes")
        (flags,) = struct.unpack_from(">I", payload)
        name, off = read_cstr(payload, 4, what="parameter name")
        if off >= len(payload):
            raise RemoteProtocolError("C_MC without a value")
        return cls(name, read_cstr(payload, off, what="parameter value")[0], flags)


@register
@dataclass(frozen=True, slots=True)
class ReadDataPath(Message):
    """``R_DP``: read a value by data path (iTNC 530, docs/lsv2.md#data-paths)."""

    MNEMONIC: ClassVar[str] = "R_DP"
    path: str
    prefix: int = 0
    """The leading u32 (meaning unknown, always 0)."""

    def to_payload(self) -> bytes:
        return _pack(">I", self.prefix) + cstr(self.path)

    @classmethod
    def from_payload(cls, payload: bytes) -> Self:
        if len(payload) < 5:
            raise RemoteProtocolError(f"R_DP needs 4 bytes and a path, got {len(payload)}")
        (prefix,) = struct.unpack_from(">I", payload)
        return cls(read_cstr(payload, 4, what="data path")[0], prefix)


DataValue = int | float | str | bool

_DP_FORMATS: dict[int, str] = {
    DataType.INT16: ">h",
    DataType.INT32: ">i",
    DataType.FLOAT64: "<d",
    DataType.BOOL: ">?",
    DataType.INT8: ">b",
    DataType.UINT8: ">B",
}


@register
@dataclass(frozen=True, slots=True)
class DataPathReply(Message):
    """``S_DP``: ``u32`` value type (:class:`DataType`) and the typed value."""

    MNEMONIC: ClassVar[str] = "S_DP"
    value_type: int
    value: DataValue

    def to_payload(self) -> bytes:
        head = _pack(">I", self.value_type)
        if self.value_type == DataType.STRING:
            if not isinstance(self.value, str):
                raise InputError(f"S_DP string value expected, got {self.value!r}")
            return head + cstr(self.value)
        fmt = _DP_FORMATS.get(self.value_type)
        if fmt is None:
            raise InputError(f"S_DP value type {self.value_type} unknown")
        return head + _pack(fmt, self.value)

    @classmethod
    def from_payload(cls, payload: bytes) -> Self:
        if len(payload) < 4:
            raise RemoteProtocolError(f"S_DP needs a 4-byte type, got {len(payload)}")
        (vtype,) = struct.unpack_from(">I", payload)
        body = payload[4:]
        if vtype == DataType.STRING:
            return cls(vtype, read_cstr(body, 0, what="S_DP string")[0])
        fmt = _DP_FORMATS.get(vtype)
        if fmt is None:
            raise RemoteProtocolError(f"S_DP value type {vtype} unknown")
        size = struct.calcsize(fmt)
        if len(body) < size:
            raise RemoteProtocolError(f"S_DP type {vtype} needs {size} bytes, got {len(body)}")
        (value,) = struct.unpack_from(fmt, body)
        if vtype == DataType.BOOL:
            value = body[0] != 0
        return cls(vtype, value)


@register
@dataclass(frozen=True, slots=True)
class ReadRunInfo(Message):
    """``R_RI``: run-time information selector (docs/lsv2.md#run-time-information)."""

    MNEMONIC: ClassVar[str] = "R_RI"
    selector: int

    def to_payload(self) -> bytes:
        return _pack(">H", self.selector)

    @classmethod
    def from_payload(cls, payload: bytes) -> Self:
        _exact(payload, 2, "R_RI")
        return cls(int.from_bytes(payload, "big"))


@register
@dataclass(frozen=True, slots=True)
class RunInfoReply(Message):
    """``S_RI``: raw answer; its layout depends on the selector (see :meth:`value`)."""

    MNEMONIC: ClassVar[str] = "S_RI"
    data: bytes

    def value(self, selector: int) -> RunInfoValue:
        """Decode the payload as the answer to ``selector``."""
        return decode_run_info(selector, self.data)

    def to_payload(self) -> bytes:
        return self.data

    @classmethod
    def from_payload(cls, payload: bytes) -> Self:
        return cls(payload)


# --- keyboard -------------------------------------------------------------------------------


@register
@dataclass(frozen=True, slots=True)
class LockKeyboard(Message):
    """``C_LK``: lock (``True``) or unlock the control's keyboard."""

    MNEMONIC: ClassVar[str] = "C_LK"
    locked: bool

    def to_payload(self) -> bytes:
        return b"\x01" if self.locked else b"\x00"

    @classmethod
    def from_payload(cls, payload: bytes) -> Self:
        _exact(payload, 1, "C_LK")
        # Old serial clients sent ASCII "0"/"1"; both forms read the same.
        return cls(payload[0] not in (0, 0x30))


@register
@dataclass(frozen=True, slots=True)
class EmulateKey(Message):
    """``C_EK``: press key ``code`` (docs/lsv2.md#key-codes)."""

    MNEMONIC: ClassVar[str] = "C_EK"
    code: int

    def to_payload(self) -> bytes:
        return _pack(">H", self.code)

    @classmethod
    def from_payload(cls, payload: bytes) -> Self:
        _exact(payload, 2, "C_EK")
        return cls(int.from_bytes(payload, "big"))


# --- scope ----------------------------------------------------------------------------------


@register
@dataclass(frozen=True, slots=True)
class ReadScopeChannels(Message):
    """``R_OC``: list scope channels (answered like a directory listing)."""

    MNEMONIC: ClassVar[str] = "R_OC"


@register
@dataclass(frozen=True, slots=True)
class ScopeChannelReply(Message):
    """``S_OC``: one channel description."""

    MNEMONIC: ClassVar[str] = "S_OC"
    channel: ScopeChannel

    def to_payload(self) -> bytes:
        return self.channel.to_bytes()

    @classmethod
    def from_payload(cls, payload: bytes) -> Self:
        return cls(ScopeChannel.from_bytes(payload))


@register
@dataclass(frozen=True, slots=True)
class ScopeSelect(Message):
    """``R_OP``: sampling interval (µs) and the selected signals."""

    MNEMONIC: ClassVar[str] = "R_OP"
    interval: int
    signals: tuple[ScopeSignal, ...]

    def to_payload(self) -> bytes:
        return _pack(">I", self.interval) + b"".join(s.to_bytes() for s in self.signals)

    @classmethod
    def from_payload(cls, payload: bytes) -> Self:
        if len(payload) < 4 or (len(payload) - 4) % 8:
            raise RemoteProtocolError(f"R_OP length {len(payload)} is not 4 + 8 × n")
        (interval,) = struct.unpack_from(">I", payload)
        sigs = tuple(ScopeSignal.from_bytes(payload, o) for o in range(4, len(payload), 8))
        return cls(interval, sigs)


@register
@dataclass(frozen=True, slots=True)
class ScopeSignalReply(Message):
    """``S_OP``: unit, factor and offset per selected signal."""

    MNEMONIC: ClassVar[str] = "S_OP"
    signals: tuple[ScopeSignalInfo, ...]

    def to_payload(self) -> bytes:
        return b"".join(s.to_bytes() for s in self.signals)

    @classmethod
    def from_payload(cls, payload: bytes) -> Self:
        if len(payload) % 22:
            raise RemoteProtocolError(f"S_OP length {len(payload)} is not a multiple of 22")
        return cls(
            tuple(ScopeSignalInfo.from_bytes(payload, o) for o in range(0, len(payload), 22))
        )


@register
@dataclass(frozen=True, slots=True)
class ScopeStart(Message):
    """``R_OD``: start recording (16 bytes; meaning of the first fields partly guessed)."""

    MNEMONIC: ClassVar[str] = "R_OD"
    interval: int
    trigger_channel: int = 6
    trigger_mode: int = 0xFFFF
    level: int = 0
    pre_trigger: int = 0

    def to_payload(self) -> bytes:
        return _pack(
            ">HHIII",
            self.trigger_channel,
            self.trigger_mode,
            self.level,
            self.pre_trigger,
            self.interval,
        )

    @classmethod
    def from_payload(cls, payload: bytes) -> Self:
        _exact(payload, 16, "R_OD")
        ch, mode, level, pre, interval = struct.unpack(">HHIII", payload)
        return cls(interval, ch, mode, level, pre)


@register
@dataclass(frozen=True, slots=True)
class ScopeDataReply(Message):
    """``S_OD``: sequence number and one sample block per selected signal."""

    MNEMONIC: ClassVar[str] = "S_OD"
    sequence: int
    blocks: tuple[ScopeSamples, ...]

    def to_payload(self) -> bytes:
        return _pack(">I", self.sequence) + b"".join(b.to_bytes() for b in self.blocks)

    @classmethod
    def from_payload(cls, payload: bytes) -> Self:
        if len(payload) < 4 or (len(payload) - 4) % ScopeSamples.SIZE:
            raise RemoteProtocolError(f"S_OD length {len(payload)} is not 4 + 134 × n")
        (seq,) = struct.unpack_from(">I", payload)
        step = ScopeSamples.SIZE
        blocks = tuple(ScopeSamples.from_bytes(payload, o) for o in range(4, len(payload), step))
        return cls(seq, blocks)


# --- telegrams that exist but whose layout is not public ------------------------------------


@dataclass(frozen=True, slots=True)
class Opaque(Message):
    """A known telegram name without a public layout (docs/lsv2.md#screen-requests,
    docs/lsv2.md#dnc-telegrams): raw payload."""

    name: str
    payload: bytes = b""

    @property
    def mnemonic(self) -> str:
        return self.name

    def to_payload(self) -> bytes:
        return self.payload


OPAQUE_NAMES = [
    "R_MP",
    "R_CD",
    "R_FO",
    "R_LB",
    "R_PD",
    "R_RS",
    "R_SD",
    "R_SE",
    "R_SP",
    "R_SS",
    "R_SW",
    "R_WD",
    "C_NC",
    "C_CN",
    "X_PC",
    "X_OK",
    "X_ER",
    "C_DS",
    "C_GC",
    "C_MB",
    "C_OP",
    "C_TP",
    "R_DS",
    "R_IN",
    "S_IN",
    "R_OH",
    "R_OI",
]


def _opaque_decoder(name: str) -> _Decoder:
    def decode_opaque(payload: bytes) -> Message:
        return Opaque(name, payload)

    return decode_opaque


for _name in OPAQUE_NAMES:
    REGISTRY[_name] = _opaque_decoder(_name)
