"""File-system telegrams: directories, file info, uploads and downloads."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Self

from opendnc.errors import RemoteProtocolError
from opendnc.lsv2.messages.base import (
    Message,
    _pack,
    register,
)
from opendnc.lsv2.payloads import (
    DirectoryInfo,
    FileEntry,
    cstr,
    read_cstr,
)

# --- file system ----------------------------------------------------------------------------


@register
@dataclass(frozen=True, slots=True)
class ReadDirInfo(Message):
    """``R_DI``: info on the current directory."""

    MNEMONIC: ClassVar[str] = "R_DI"


@register
@dataclass(frozen=True, slots=True)
class DirInfoReply(Message):
    """``S_DI``: :class:`DirectoryInfo`."""

    MNEMONIC: ClassVar[str] = "S_DI"
    info: DirectoryInfo

    def to_payload(self) -> bytes:
        return self.info.to_bytes()

    @classmethod
    def from_payload(cls, payload: bytes) -> Self:
        return cls(DirectoryInfo.from_bytes(payload))


@register
@dataclass(frozen=True, slots=True)
class ReadDir(Message):
    """``R_DR``: list the current directory (mode 0 single, 1 multi) or drives (2)."""

    MNEMONIC: ClassVar[str] = "R_DR"
    mode: int = 0

    def to_payload(self) -> bytes:
        return _pack(">B", self.mode)

    @classmethod
    def from_payload(cls, payload: bytes) -> Self:
        # Some clients sent the mode as u16; the last byte is the mode either way.
        return cls(payload[-1] if payload else 0)


@register
@dataclass(frozen=True, slots=True)
class DirReply(Message):
    """``S_DR``: one or more file / directory / drive entries."""

    MNEMONIC: ClassVar[str] = "S_DR"
    entries: tuple[FileEntry, ...]

    def to_payload(self) -> bytes:
        return b"".join(e.to_bytes() for e in self.entries)

    @classmethod
    def from_payload(cls, payload: bytes) -> Self:
        return cls(FileEntry.read_all(payload))


@dataclass(frozen=True, slots=True)
class _PathMessage(Message):
    path: str

    def to_payload(self) -> bytes:
        return cstr(self.path)

    @classmethod
    def from_payload(cls, payload: bytes) -> Self:
        if not payload:
            raise RemoteProtocolError(f"{cls.MNEMONIC} without a path")
        return cls(read_cstr(payload, 0, what="path")[0])


@register
@dataclass(frozen=True, slots=True)
class ReadFileInfo(_PathMessage):
    """``R_FI``: info on a file or directory."""

    MNEMONIC: ClassVar[str] = "R_FI"


@register
@dataclass(frozen=True, slots=True)
class FileInfoReply(Message):
    """``S_FI``: one :class:`FileEntry`."""

    MNEMONIC: ClassVar[str] = "S_FI"
    entry: FileEntry

    def to_payload(self) -> bytes:
        return self.entry.to_bytes()

    @classmethod
    def from_payload(cls, payload: bytes) -> Self:
        return cls(FileEntry.from_bytes(payload))


@register
@dataclass(frozen=True, slots=True)
class ChangeDir(_PathMessage):
    """``C_DC``: change the current directory."""

    MNEMONIC: ClassVar[str] = "C_DC"


@register
@dataclass(frozen=True, slots=True)
class MakeDir(_PathMessage):
    """``C_DM``: create one directory level."""

    MNEMONIC: ClassVar[str] = "C_DM"


@register
@dataclass(frozen=True, slots=True)
class DeleteDir(_PathMessage):
    """``C_DD``: delete an empty directory."""

    MNEMONIC: ClassVar[str] = "C_DD"


@register
@dataclass(frozen=True, slots=True)
class DeleteFile(_PathMessage):
    """``C_FD``: delete a file."""

    MNEMONIC: ClassVar[str] = "C_FD"


@dataclass(frozen=True, slots=True)
class _TwoPaths(Message):
    source: str
    target: str

    def to_payload(self) -> bytes:
        return cstr(self.source) + cstr(self.target)

    @classmethod
    def from_payload(cls, payload: bytes) -> Self:
        source, off = read_cstr(payload, 0, what="source path")
        if off >= len(payload):
            raise RemoteProtocolError(f"{cls.MNEMONIC} without a target path")
        return cls(source, read_cstr(payload, off, what="target path")[0])


@register
@dataclass(frozen=True, slots=True)
class CopyFile(_TwoPaths):
    """``C_FC``: copy ``source`` (name in the current directory) to ``target``."""

    MNEMONIC: ClassVar[str] = "C_FC"


@register
@dataclass(frozen=True, slots=True)
class MoveFile(_TwoPaths):
    """``C_FR``: move / rename ``source`` (name in the current directory) to ``target``."""

    MNEMONIC: ClassVar[str] = "C_FR"


@register
@dataclass(frozen=True, slots=True)
class ChangeAttributes(Message):
    """``C_FA``: change file attributes (layout unknown; raw bytes)."""

    MNEMONIC: ClassVar[str] = "C_FA"
    data: bytes = b""

    def to_payload(self) -> bytes:
        return self.data

    @classmethod
    def from_payload(cls, payload: bytes) -> Self:
        return cls(payload)


@dataclass(frozen=True, slots=True)
class _FileRequest(Message):
    path: str
    mode: int | None = None
    """Transfer mode byte (docs/lsv2.md#transfer-mode); ``None`` = absent (ASCII)."""

    def to_payload(self) -> bytes:
        return cstr(self.path) + (b"" if self.mode is None else _pack(">B", self.mode))

    @classmethod
    def from_payload(cls, payload: bytes) -> Self:
        path, off = read_cstr(payload, 0, what="path")
        if not path:
            raise RemoteProtocolError(f"{cls.MNEMONIC} without a path")
        rest = payload[off:]
        if len(rest) > 1:
            raise RemoteProtocolError(f"{cls.MNEMONIC}: {len(rest)} bytes after the path")
        return cls(path, rest[0] if rest else None)


@register
@dataclass(frozen=True, slots=True)
class SendFile(_FileRequest):
    """``C_FL``: start an upload to ``path``."""

    MNEMONIC: ClassVar[str] = "C_FL"


@register
@dataclass(frozen=True, slots=True)
class ReadFile(_FileRequest):
    """``R_FL``: start a download of ``path``."""

    MNEMONIC: ClassVar[str] = "R_FL"


@register
@dataclass(frozen=True, slots=True)
class FileData(Message):
    """``S_FL``: one block of file data (either direction)."""

    MNEMONIC: ClassVar[str] = "S_FL"
    data: bytes

    def to_payload(self) -> bytes:
        return self.data

    @classmethod
    def from_payload(cls, payload: bytes) -> Self:
        return cls(payload)
