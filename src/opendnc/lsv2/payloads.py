"""Typed data layouts carried inside LSV2 telegrams (docs/lsv2.md#telegram-names,
docs/lsv2.md#system-parameters, docs/lsv2.md#remote-scope).

Each structure converts to and from bytes (``to_bytes()`` / ``from_bytes()``). Decoders raise
:class:`~opendnc.errors.RemoteProtocolError` naming the field that did not fit; encoders raise
:class:`~opendnc.errors.InputError` for values that cannot be expressed on the wire.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from opendnc.errors import InputError, RemoteProtocolError
from opendnc.lsv2.constants import AttributeScheme

__all__ = [
    "DirectoryInfo",
    "FileEntry",
    "ScopeChannel",
    "ScopeSamples",
    "ScopeSignal",
    "ScopeSignalInfo",
    "SystemParameters",
    "Versions",
    "cstr",
    "from_wire_ascii",
    "read_cstr",
    "split_cstrs",
    "to_wire_ascii",
]

ENCODING = "latin-1"


def cstr(text: str) -> bytes:
    """Encode ``text`` as a NUL-terminated Latin-1 string."""
    try:
        raw = text.encode(ENCODING)
    except UnicodeEncodeError as exc:
        raise InputError(f"{text!r} cannot be sent: LSV2 text is Latin-1") from exc
    if b"\0" in raw:
        raise InputError(f"{text!r} contains a NUL character")
    return raw + b"\0"


def read_cstr(data: bytes, offset: int = 0, *, what: str = "string") -> tuple[str, int]:
    """Read a NUL-terminated string at ``offset``; return it and the offset after the NUL.

    A missing final NUL is tolerated (the string then runs to the end of ``data``).
    """
    if offset > len(data):
        raise RemoteProtocolError(f"{what} missing: payload ends at byte {len(data)}")
    end = data.find(b"\0", offset)
    if end < 0:
        return data[offset:].decode(ENCODING), len(data)
    return data[offset:end].decode(ENCODING), end + 1


def split_cstrs(data: bytes) -> tuple[str, ...]:
    """Split back-to-back NUL-terminated strings (a missing last NUL is tolerated)."""
    if not data:
        return ()
    if data.endswith(b"\0"):
        data = data[:-1]
    return tuple(part.decode(ENCODING) for part in data.split(b"\0"))


def join_cstrs(parts: tuple[str, ...] | list[str]) -> bytes:
    """Encode strings back to back, each NUL-terminated."""
    return b"".join(cstr(p) for p in parts)


def to_wire_ascii(data: bytes) -> bytes:
    """ASCII transfer mode: each line travels terminated by one NUL (CR LF or LF -> NUL)."""
    return data.replace(b"\r\n", b"\n").replace(b"\n", b"\0")


def from_wire_ascii(data: bytes, line_end: bytes = b"\r\n") -> bytes:
    """Undo :func:`to_wire_ascii`: every NUL line end becomes ``line_end``."""
    return data.replace(b"\0", line_end)


def _need(data: bytes, size: int, what: str) -> None:
    if len(data) < size:
        raise RemoteProtocolError(f"{what} needs {size} bytes, got {len(data)}")


# --- system parameters (docs/lsv2.md#system-parameters) -------------------------------------------

_PR = struct.Struct(">14I B 7s 4I 16s BBH 4B I I HH I")
assert _PR.size == 120


@dataclass(frozen=True, slots=True)
class SystemParameters:
    """The ``S_PR`` answer: PLC memory map, protocol limits and feature flags."""

    markers_start: int
    markers: int
    inputs_start: int
    inputs: int
    outputs_start: int
    outputs: int
    counters_start: int
    counters: int
    timers_start: int
    timers: int
    words_start: int
    words: int
    strings_start: int
    strings: int
    string_length: int
    input_words_start: int
    input_words: int
    output_words_start: int
    output_words: int
    lsv2_version: int
    lsv2_flags: int
    max_block_length: int
    bin_version: int = 0
    bin_revision: int = 0
    iso_version: int = 0
    iso_revision: int = 0
    hardware_version: int = 0
    lsv2_flags_ex: int = 0
    max_trace_lines: int = 0
    scope_channels: int = 0
    password_key: int = 0
    extra: int | None = None
    """The unknown last u32 of the 124-byte form (iTNC 530 machines); ``None`` = 120 bytes."""
    reserved1: bytes = bytes(7)
    reserved2: bytes = bytes(16)

    @classmethod
    def from_bytes(cls, data: bytes) -> SystemParameters:
        """Decode a 120- or 124-byte ``S_PR`` payload."""
        if len(data) not in (120, 124):
            raise RemoteProtocolError(f"S_PR payload must be 120 or 124 bytes, got {len(data)}")
        v: tuple[int, ...] = _PR.unpack_from(data)
        extra = int.from_bytes(data[120:124], "big") if len(data) == 124 else None
        return cls(
            markers_start=v[0],
            markers=v[1],
            inputs_start=v[2],
            inputs=v[3],
            outputs_start=v[4],
            outputs=v[5],
            counters_start=v[6],
            counters=v[7],
            timers_start=v[8],
            timers=v[9],
            words_start=v[10],
            words=v[11],
            strings_start=v[12],
            strings=v[13],
            string_length=v[14],
            reserved1=data[57:64],
            input_words_start=v[16],
            input_words=v[17],
            output_words_start=v[18],
            output_words=v[19],
            reserved2=data[80:96],
            lsv2_version=v[21],
            lsv2_flags=v[22],
            max_block_length=v[23],
            bin_version=v[24],
            bin_revision=v[25],
            iso_version=v[26],
            iso_revision=v[27],
            hardware_version=v[28],
            lsv2_flags_ex=v[29],
            max_trace_lines=v[30],
            scope_channels=v[31],
            password_key=v[32],
            extra=extra,
        )

    def to_bytes(self) -> bytes:
        """Encode as the 120- or 124-byte ``S_PR`` payload."""
        try:
            raw = _PR.pack(
                self.markers_start,
                self.markers,
                self.inputs_start,
                self.inputs,
                self.outputs_start,
                self.outputs,
                self.counters_start,
                self.counters,
                self.timers_start,
                self.timers,
                self.words_start,
                self.words,
                self.strings_start,
                self.strings,
                self.string_length,
                self.reserved1,
                self.input_words_start,
                self.input_words,
                self.output_words_start,
                self.output_words,
                self.reserved2,
                self.lsv2_version,
                self.lsv2_flags,
                self.max_block_length,
                self.bin_version,
                self.bin_revision,
                self.iso_version,
                self.iso_revision,
                self.hardware_version,
                self.lsv2_flags_ex,
                self.max_trace_lines,
                self.scope_channels,
                self.password_key,
            )
            if self.extra is not None:
                raw += struct.pack(">I", self.extra)
        except struct.error as exc:
            raise InputError(f"system parameter out of range: {exc}") from exc
        return raw


# --- versions (docs/lsv2.md#versions) -------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Versions:
    """Version strings of a control (the empty ``R_VR`` answer plus optional selectors)."""

    model: str
    nc_software: str
    plc: str
    options: str
    splc: str | None = None
    """SPLC version: the fifth part of a 5-part answer (TNC 3xx/6xx), else ``None``."""
    control_id: str | None = None
    release_type: str | None = None

    @classmethod
    def from_parts(cls, parts: tuple[str, ...]) -> Versions:
        """Interpret the 4 or 5 strings of the empty ``R_VR`` answer."""
        if len(parts) == 4:
            return cls(parts[0], parts[1], parts[2], parts[3])
        if len(parts) == 5:
            return cls(parts[0], parts[1], parts[2], parts[4], splc=parts[3])
        raise RemoteProtocolError(f"S_VR must carry 4 or 5 version strings, got {len(parts)}")

    def to_parts(self) -> tuple[str, ...]:
        """The strings of the empty ``R_VR`` answer (5 when an SPLC version is known)."""
        if self.splc is None:
            return (self.model, self.nc_software, self.plc, self.options)
        return (self.model, self.nc_software, self.plc, self.splc, self.options)


# --- file and directory entries (docs/lsv2.md#directory-info, docs/lsv2.md#file-entries) ----------

_ENTRY = struct.Struct(">III")


@dataclass(frozen=True, slots=True)
class FileEntry:
    """A file, directory or drive entry of ``S_FI`` / ``S_DR``.

    ``attributes`` keeps the raw bits; their meaning depends on the control's
    :class:`~opendnc.lsv2.constants.AttributeScheme`, so ask with ``is_directory(scheme)``.
    """

    name: str
    size: int = 0
    mtime: int = 0
    """Modification time, seconds since 1970."""
    attributes: int = 0

    def is_directory(self, scheme: AttributeScheme) -> bool:
        """True if the entry is a directory under ``scheme``."""
        return bool(self.attributes & scheme.directory_bit)

    def is_write_protected(self, scheme: AttributeScheme) -> bool:
        """True if the entry is write-protected under ``scheme``."""
        return bool(self.attributes & scheme.write_protected_bit)

    def is_hidden(self) -> bool:
        """Hidden bit (same in both schemes)."""
        return bool(self.attributes & 0x08)

    def is_selected(self, scheme: AttributeScheme) -> bool:
        """Selected (active program) bit; only the new scheme has one."""
        return scheme is AttributeScheme.NEW and bool(self.attributes & 0x80)

    def to_bytes(self) -> bytes:
        """Encode as ``u32 size, u32 mtime, u32 attributes, cstr name``."""
        try:
            head = _ENTRY.pack(self.size, self.mtime, self.attributes)
        except struct.error as exc:
            raise InputError(f"file entry field out of range: {exc}") from exc
        return head + cstr(self.name)

    @classmethod
    def from_bytes(cls, data: bytes) -> FileEntry:
        """Decode exactly one entry (trailing bytes after the name's NUL are ignored)."""
        entry, _ = cls.read(data, 0)
        return entry

    @classmethod
    def read(cls, data: bytes, offset: int) -> tuple[FileEntry, int]:
        """Decode one entry at ``offset``; return it and the offset of the next one."""
        if len(data) - offset < 12:
            raise RemoteProtocolError(
                f"file entry needs at least 12 bytes, got {len(data) - offset}"
            )
        size, mtime, attributes = _ENTRY.unpack_from(data, offset)
        name, end = read_cstr(data, offset + 12, what="file entry name")
        return cls(name, size, mtime, attributes), end

    @classmethod
    def read_all(cls, data: bytes) -> tuple[FileEntry, ...]:
        """Decode entries packed back to back (``R_DR`` multi mode)."""
        entries: list[FileEntry] = []
        offset = 0
        while offset < len(data):
            entry, offset = cls.read(data, offset)
            entries.append(entry)
        return tuple(entries)


_DI_HEAD = struct.Struct(">I128s32s")


@dataclass(frozen=True, slots=True)
class DirectoryInfo:
    """``S_DI``: free space and path of the current directory (path ends with a separator)."""

    free_bytes: int
    path: str
    attribute_tags: tuple[str, ...] = ()
    """Short attribute tags (meaning unknown), trailing empty slots dropped."""
    attribute_values: bytes = bytes(32)

    def to_bytes(self) -> bytes:
        """Encode (at least 165 bytes)."""
        if len(self.attribute_tags) > 32 or len(self.attribute_values) != 32:
            raise InputError("directory info holds 32 attribute tags and 32 values")
        tags = b"".join(cstr(t)[:-1].ljust(4, b"\0")[:4] for t in self.attribute_tags)
        try:
            head = _DI_HEAD.pack(self.free_bytes, tags, self.attribute_values)
        except struct.error as exc:
            raise InputError(f"directory info field out of range: {exc}") from exc
        return head + cstr(self.path)

    @classmethod
    def from_bytes(cls, data: bytes) -> DirectoryInfo:
        """Decode an ``S_DI`` payload."""
        _need(data, 165, "S_DI payload")
        free, tags_raw, values = _DI_HEAD.unpack_from(data)
        tags = [tags_raw[i : i + 4].rstrip(b"\0").decode(ENCODING) for i in range(0, 128, 4)]
        while tags and not tags[-1]:
            tags.pop()
        path, _ = read_cstr(data, 164, what="directory path")
        return cls(free, path, tuple(tags), values)


# --- scope (docs/lsv2.md#remote-scope) ------------------------------------------------------------

_OC_HEAD = struct.Struct(">HHHHH36x")
assert _OC_HEAD.size == 46


@dataclass(frozen=True, slots=True)
class ScopeChannel:
    """One ``S_OC`` channel description."""

    number: int
    interval: int
    """Minimum sampling interval in µs."""
    channel_type: int
    name: str
    signals: tuple[str, ...] = ()
    """Signal labels (axis letters or PLC operand names; ``-`` = unused slot)."""

    def to_bytes(self) -> bytes:
        """Encode: 46-byte header, 13-byte name slot, then the label strings."""
        name = cstr(self.name)
        if len(name) > 13:
            raise InputError(f"scope channel name {self.name!r} longer than 12 characters")
        try:
            head = _OC_HEAD.pack(self.number, self.interval, self.channel_type, 0, self.interval)
        except struct.error as exc:
            raise InputError(f"scope channel field out of range: {exc}") from exc
        return head + name.ljust(13, b"\0") + join_cstrs(self.signals)

    @classmethod
    def from_bytes(cls, data: bytes) -> ScopeChannel:
        """Decode an ``S_OC`` payload."""
        _need(data, 59, "S_OC payload")
        number, interval, ctype, _, _ = _OC_HEAD.unpack_from(data)
        name, _ = read_cstr(data[46:59], 0, what="scope channel name")
        return cls(number, interval, ctype, name, split_cstrs(data[59:]))


_SIGNAL_SEL = struct.Struct(">HHI")


@dataclass(frozen=True, slots=True)
class ScopeSignal:
    """One signal selector of ``R_OP``: channel, signal index or operand type, address."""

    channel: int
    selector: int = 0xFFFF
    """Signal index (axis channels), PLC operand type (PLC channels) or 0xFFFF (none)."""
    address: int = 0xFFFFFFFF
    """PLC operand address, or 0xFFFFFFFF."""

    def to_bytes(self) -> bytes:
        """Encode as 8 bytes."""
        try:
            return _SIGNAL_SEL.pack(self.channel, self.selector, self.address)
        except struct.error as exc:
            raise InputError(f"scope signal field out of range: {exc}") from exc

    @classmethod
    def from_bytes(cls, data: bytes, offset: int = 0) -> ScopeSignal:
        """Decode 8 bytes at ``offset``."""
        return cls(*_SIGNAL_SEL.unpack_from(data, offset))


@dataclass(frozen=True, slots=True)
class ScopeSignalInfo:
    """One 22-byte ``S_OP`` record: unit text, scale factor, offset."""

    unit: str
    factor: float
    offset: int = 0

    def to_bytes(self) -> bytes:
        """Encode: unit NUL-padded to 10 bytes, ``f64le`` factor, ``i32`` offset."""
        unit = cstr(self.unit)[:-1]
        if len(unit) > 10:
            raise InputError(f"scope unit {self.unit!r} longer than 10 bytes")
        try:
            # The offset is big-endian like every other integer; only the double is LE.
            return (
                unit.ljust(10, b"\0")
                + struct.pack("<d", self.factor)
                + struct.pack(">i", self.offset)
            )
        except struct.error as exc:
            raise InputError(f"scope signal info out of range: {exc}") from exc

    @classmethod
    def from_bytes(cls, data: bytes, offset: int = 0) -> ScopeSignalInfo:
        """Decode 22 bytes at ``offset``."""
        unit, _ = read_cstr(data[offset : offset + 10], 0, what="scope unit")
        (factor,) = struct.unpack_from("<d", data, offset + 10)
        (off,) = struct.unpack_from(">i", data, offset + 18)
        return cls(unit, factor, off)


@dataclass(frozen=True, slots=True)
class ScopeSamples:
    """One signal's block inside ``S_OD``: 32 raw samples (value = raw × factor + offset)."""

    samples: tuple[int, ...]
    count: int = 32
    marker: int = 0xFFFFFFFF

    SIZE = 134

    def to_bytes(self) -> bytes:
        """Encode as 134 bytes."""
        if len(self.samples) != 32:
            raise InputError(f"a scope block holds 32 samples, got {len(self.samples)}")
        try:
            return struct.pack(">HI32i", self.count, self.marker, *self.samples)
        except struct.error as exc:
            raise InputError(f"scope sample out of range: {exc}") from exc

    @classmethod
    def from_bytes(cls, data: bytes, offset: int = 0) -> ScopeSamples:
        """Decode 134 bytes at ``offset``."""
        count, marker, *samples = struct.unpack_from(">HI32i", data, offset)
        return cls(tuple(samples), count, marker)
