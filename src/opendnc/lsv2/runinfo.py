"""Typed ``S_RI`` payloads: the layout of a run-time answer depends on the selector asked.

``decode_run_info(selector, data)`` and ``encode_run_info(selector, value)`` are used by the
client (decoding) and the simulator (encoding), so both sides share one definition of each
layout (docs/lsv2.md#run-time-information, docs/lsv2.md#nc-errors).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from opendnc.errors import InputError, RemoteProtocolError
from opendnc.lsv2.constants import ExecutionMode, ProgramState, RunInfo
from opendnc.lsv2.payloads import cstr, read_cstr

__all__ = [
    "AxesConfig",
    "AxesNames",
    "AxesPositions",
    "AxisConfig",
    "AxisName",
    "AxisPosition",
    "NcError",
    "Overrides",
    "RunInfoValue",
    "SelectedProgram",
    "ToolInfo",
    "decode_run_info",
    "encode_run_info",
]


def _need(data: bytes, size: int, what: str) -> None:
    if len(data) < size:
        raise RemoteProtocolError(f"{what} needs {size} bytes, got {len(data)}")


def _strings(data: bytes, offset: int, count: int, what: str) -> tuple[list[str], int]:
    out: list[str] = []
    for _ in range(count):
        if offset >= len(data):
            raise RemoteProtocolError(f"{what}: expected {count} strings, got {len(out)}")
        text, offset = read_cstr(data, offset, what=what)
        out.append(text)
    return out, offset


def _pack(fmt: str, *values: object) -> bytes:
    try:
        return struct.pack(fmt, *values)
    except struct.error as exc:
        raise InputError(f"run-time value out of range: {exc}") from exc


@dataclass(frozen=True, slots=True)
class AxisConfig:
    """One axis of selector 20."""

    axis_id: int
    config: int
    name: str


@dataclass(frozen=True, slots=True)
class AxesConfig:
    """Selector 20: axis configuration names."""

    axes: tuple[AxisConfig, ...]

    def to_bytes(self) -> bytes:
        """``u16 n``, n × ``u16 id``, n × ``u16 config``, n × ``cstr name``."""
        n = len(self.axes)
        return _pack(
            f">H{n}H{n}H", n, *(a.axis_id for a in self.axes), *(a.config for a in self.axes)
        ) + b"".join(cstr(a.name) for a in self.axes)

    @classmethod
    def from_bytes(cls, data: bytes) -> AxesConfig:
        """Decode selector 20."""
        _need(data, 2, "axis configuration")
        (n,) = struct.unpack_from(">H", data)
        _need(data, 2 + 4 * n, "axis configuration")
        ids = struct.unpack_from(f">{n}H", data, 2)
        cfg = struct.unpack_from(f">{n}H", data, 2 + 2 * n)
        names, _ = _strings(data, 2 + 4 * n, n, "axis configuration names")
        return cls(tuple(AxisConfig(i, c, s) for i, c, s in zip(ids, cfg, names, strict=True)))


@dataclass(frozen=True, slots=True)
class AxisName:
    """One axis of selector 21."""

    axis_id: int
    value: str
    name: str


@dataclass(frozen=True, slots=True)
class AxesNames:
    """Selector 21: physical axis names."""

    axes: tuple[AxisName, ...]

    def to_bytes(self) -> bytes:
        """``u16 n``, n × ``u16 id``, n × ``cstr value``, n × ``cstr name``."""
        n = len(self.axes)
        return (
            _pack(f">H{n}H", n, *(a.axis_id for a in self.axes))
            + b"".join(cstr(a.value) for a in self.axes)
            + b"".join(cstr(a.name) for a in self.axes)
        )

    @classmethod
    def from_bytes(cls, data: bytes) -> AxesNames:
        """Decode selector 21."""
        _need(data, 2, "axis names")
        (n,) = struct.unpack_from(">H", data)
        _need(data, 2 + 2 * n, "axis names")
        ids = struct.unpack_from(f">{n}H", data, 2)
        values, off = _strings(data, 2 + 2 * n, n, "axis name values")
        names, _ = _strings(data, off, n, "axis names")
        return cls(tuple(AxisName(i, v, s) for i, v, s in zip(ids, values, names, strict=True)))


@dataclass(frozen=True, slots=True)
class AxisPosition:
    """One axis of selector 22: its letter and position (text as sent, and as a number)."""

    name: str
    text: str

    @property
    def value(self) -> float:
        """The position as a float (the text was checked when decoded)."""
        return float(self.text)


@dataclass(frozen=True, slots=True)
class AxesPositions:
    """Selector 22: current axis positions."""

    axes: tuple[AxisPosition, ...]
    flag: int = 0
    """Leading byte of unknown meaning (0 in all captures)."""

    def as_dict(self) -> dict[str, float]:
        """Axis letter -> position."""
        return {a.name: a.value for a in self.axes}

    def to_bytes(self) -> bytes:
        """``u8 flag``, ``i8 n``, n × ``cstr value``, n × ``cstr letter``."""
        return (
            _pack(">Bb", self.flag, len(self.axes))
            + b"".join(cstr(a.text) for a in self.axes)
            + b"".join(cstr(a.name) for a in self.axes)
        )

    @classmethod
    def from_bytes(cls, data: bytes) -> AxesPositions:
        """Decode selector 22."""
        _need(data, 2, "axis positions")
        flag, n = struct.unpack_from(">Bb", data)
        if n < 0:
            raise RemoteProtocolError(f"axis positions: negative axis count {n}")
        values, off = _strings(data, 2, n, "axis position values")
        names, _ = _strings(data, off, n, "axis letters")
        for text in values:
            try:
                float(text)
            except ValueError:
                raise RemoteProtocolError(f"axis position {text!r} is not a number") from None
        return cls(tuple(AxisPosition(s, v) for s, v in zip(names, values, strict=True)), flag)


@dataclass(frozen=True, slots=True)
class SelectedProgram:
    """Selector 24: selected main program, current (called) program and line."""

    main: str
    current: str
    line: int = 0

    def to_bytes(self) -> bytes:
        """``u32 line``, ``cstr main``, ``cstr current``."""
        return _pack(">I", self.line) + cstr(self.main) + cstr(self.current)

    @classmethod
    def from_bytes(cls, data: bytes) -> SelectedProgram:
        """Decode selector 24."""
        _need(data, 5, "selected program")
        (line,) = struct.unpack_from(">I", data)
        main, off = read_cstr(data, 4, what="main program")
        current = read_cstr(data, off, what="current program")[0] if off < len(data) else ""
        return cls(main, current, line)


@dataclass(frozen=True, slots=True)
class Overrides:
    """Selector 25: override settings in 0.01 % (10000 = 100 %)."""

    feed: int
    spindle: int
    rapid: int

    @property
    def percent(self) -> tuple[float, float, float]:
        """Feed, spindle and rapid override in percent."""
        return (self.feed / 100, self.spindle / 100, self.rapid / 100)

    def to_bytes(self) -> bytes:
        """Three ``u32``."""
        return _pack(">III", self.feed, self.spindle, self.rapid)

    @classmethod
    def from_bytes(cls, data: bytes) -> Overrides:
        """Decode selector 25."""
        _need(data, 12, "overrides")
        return cls(*struct.unpack_from(">III", data))


@dataclass(frozen=True, slots=True)
class NcError:
    """Selectors 27/28: one NC error message."""

    error_class: int
    group: int
    number: int
    text: str

    def to_bytes(self) -> bytes:
        """``u16 class``, ``u16 group``, ``i32 number``, ``cstr text``."""
        return _pack(">HHi", self.error_class, self.group, self.number) + cstr(self.text)

    @classmethod
    def from_bytes(cls, data: bytes) -> NcError:
        """Decode selector 27/28."""
        _need(data, 8, "NC error message")
        cls_, group, number = struct.unpack_from(">HHi", data)
        text, _ = read_cstr(data, 8, what="NC error text")
        return cls(cls_, group, number, text)


@dataclass(frozen=True, slots=True)
class ToolInfo:
    """Selector 51: the tool in the spindle (length/radius only in the 24-byte form)."""

    number: int
    index: int
    axis: int
    """Tool axis: 0 X, 1 Y, 2 Z."""
    length: float | None = None
    radius: float | None = None

    def to_bytes(self) -> bytes:
        """8 bytes, or 24 with ``f64le`` length and radius."""
        head = _pack(">IHH", self.number, self.index, self.axis)
        if self.length is None or self.radius is None:
            return head
        return head + _pack("<dd", self.length, self.radius)

    @classmethod
    def from_bytes(cls, data: bytes) -> ToolInfo:
        """Decode selector 51."""
        _need(data, 8, "tool information")
        number, index, axis = struct.unpack_from(">IHH", data)
        if len(data) >= 24:
            length, radius = struct.unpack_from("<dd", data, 8)
            return cls(number, index, axis, length, radius)
        return cls(number, index, axis)


RunInfoValue = (
    AxesConfig
    | AxesNames
    | AxesPositions
    | ExecutionMode
    | SelectedProgram
    | Overrides
    | ProgramState
    | NcError
    | ToolInfo
    | int
)

_UPTIMES = {
    RunInfo.NC_UPTIME,
    RunInfo.MACHINE_UPTIME,
    RunInfo.MACHINE_RUNTIME,
    RunInfo.SPINDLE1_RUNTIME,
    RunInfo.SPINDLE2_RUNTIME,
}


def _u16_enum(data: bytes, what: str) -> int:
    _need(data, 2, what)
    return int.from_bytes(data[:2], "big")


def decode_run_info(selector: int, data: bytes) -> RunInfoValue:
    """Decode the ``S_RI`` payload answering ``R_RI selector``."""
    if selector == RunInfo.AXES_CONFIG:
        return AxesConfig.from_bytes(data)
    if selector == RunInfo.AXES_NAMES:
        return AxesNames.from_bytes(data)
    if selector == RunInfo.AXES_POSITION:
        return AxesPositions.from_bytes(data)
    if selector == RunInfo.EXEC_STATE:
        value = _u16_enum(data, "execution mode")
        try:
            return ExecutionMode(value)
        except ValueError:
            raise RemoteProtocolError(f"unknown execution mode {value}") from None
    if selector == RunInfo.SELECTED_PGM:
        return SelectedProgram.from_bytes(data)
    if selector == RunInfo.OVERRIDE:
        return Overrides.from_bytes(data)
    if selector == RunInfo.PGM_STATE:
        value = _u16_enum(data, "program state")
        try:
            return ProgramState(value)
        except ValueError:
            raise RemoteProtocolError(f"unknown program state {value}") from None
    if selector in (RunInfo.FIRST_ERROR, RunInfo.NEXT_ERROR):
        return NcError.from_bytes(data)
    if selector in _UPTIMES:
        _need(data, 4, "time counter")
        return int.from_bytes(data[:4], "big")
    if selector == RunInfo.CURRENT_TOOL:
        return ToolInfo.from_bytes(data)
    raise RemoteProtocolError(f"no known layout for R_RI selector {selector}")


_LAYOUTS: dict[
    int,
    type[AxesConfig | AxesNames | AxesPositions | SelectedProgram | Overrides | NcError | ToolInfo],
] = {
    RunInfo.AXES_CONFIG: AxesConfig,
    RunInfo.AXES_NAMES: AxesNames,
    RunInfo.AXES_POSITION: AxesPositions,
    RunInfo.SELECTED_PGM: SelectedProgram,
    RunInfo.OVERRIDE: Overrides,
    RunInfo.FIRST_ERROR: NcError,
    RunInfo.NEXT_ERROR: NcError,
    RunInfo.CURRENT_TOOL: ToolInfo,
}


def encode_run_info(selector: int, value: RunInfoValue) -> bytes:
    """Encode ``value`` as the ``S_RI`` payload answering ``R_RI selector``."""
    if selector in (RunInfo.EXEC_STATE, RunInfo.PGM_STATE):
        if not isinstance(value, int) or isinstance(value, bool):
            raise InputError(f"R_RI {selector} needs an integer state, got {value!r}")
        return _pack(">H", int(value))
    if selector in _UPTIMES:
        if not isinstance(value, int):
            raise InputError(f"R_RI {selector} needs seconds as int, got {value!r}")
        return _pack(">I", value)
    layout = _LAYOUTS.get(selector)
    if layout is None:
        raise InputError(f"no known layout for R_RI selector {selector}")
    if isinstance(value, int) or not isinstance(value, layout):
        raise InputError(f"R_RI {selector} needs {layout.__name__}, got {value!r}")
    return value.to_bytes()
