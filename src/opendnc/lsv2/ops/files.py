"""File-system operations: listings, info, directories, copy/move, uploads and downloads."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from datetime import UTC, datetime

from opendnc.errors import InputError
from opendnc.lsv2.constants import DRIVE_LOGINS, AttributeScheme, DirMode, Login, TransferMode
from opendnc.lsv2.messages import (
    BlockDefect,
    ChangeDir,
    CopyFile,
    DeleteDir,
    DeleteFile,
    DirInfoReply,
    DirReply,
    FileData,
    FileDone,
    FileInfoReply,
    MakeDir,
    Message,
    MoveFile,
    Ok,
    ReadDir,
    ReadDirInfo,
    ReadFile,
    ReadFileInfo,
    Refused,
    SendFile,
)
from opendnc.lsv2.ops.base import (
    Op,
    Receive,
    Send,
    SessionState,
    ask,
    command,
    ensure_login,
    expect,
    refuse,
    require_unsafe,
    split_path,
    wire_path,
)
from opendnc.lsv2.payloads import DirectoryInfo, FileEntry, from_wire_ascii, to_wire_ascii

__all__ = [
    "FileInfo",
    "Progress",
    "ascii_blocks",
    "change_dir",
    "copy_file",
    "delete_file",
    "dir_info",
    "download",
    "drives",
    "file_info",
    "list_dir",
    "make_dir",
    "move_file",
    "remove_dir",
    "text_size",
    "upload",
    "walk",
]

Progress = Callable[[int, int | None], None]
"""Progress callback: bytes done, total bytes (``None`` if unknown)."""

_MISSING = (32, 55)  # T_ER_NO_FILE, T_ER_NO_DIR
_SEND_NEXT = Send(Ok())  # "send the next block": one shared immutable step per block
_RECEIVE = Receive()


@dataclass(frozen=True, slots=True)
class FileInfo:
    """A file, directory or drive as the control reports it."""

    name: str
    path: str
    """Full path on the control (wire form, ``\\`` separators)."""
    size: int
    modified: datetime
    is_dir: bool
    is_drive: bool
    write_protected: bool
    hidden: bool
    selected: bool
    attributes: int

    @classmethod
    def from_entry(cls, entry: FileEntry, path: str, scheme: AttributeScheme) -> FileInfo:
        """Interpret a raw entry under the control's attribute ``scheme``."""
        is_drive = entry.name.endswith(":") or (
            scheme is AttributeScheme.NEW and bool(entry.attributes & 0x10)
        )
        return cls(
            name=entry.name.replace("/", "\\").rstrip("\\").rsplit("\\", 1)[-1] or entry.name,
            path=path,
            size=entry.size,
            modified=datetime.fromtimestamp(entry.mtime, UTC),
            is_dir=entry.is_directory(scheme) or is_drive,
            is_drive=is_drive,
            write_protected=entry.is_write_protected(scheme),
            hidden=entry.is_hidden(),
            selected=entry.is_selected(scheme),
            attributes=entry.attributes,
        )


TABLE_EXTENSIONS = frozenset({".t", ".tch", ".tab", ".d", ".htt"})
"""Tool, pocket, free and datum tables: writing them changes what the machine does."""
PROTECTED_DRIVES = ("PLC:", "SYS:")
"""PLC program / OEM configuration and system files."""


def guard_write(state: SessionState, path: str, action: str) -> None:
    """Refuse writes into tables or the PLC / system drives while safe mode is on."""
    p = wire_path(path)
    ext = p[p.rfind(".") :].lower() if "." in p.rsplit("\\", 1)[-1] else ""
    if p[:4].upper() in PROTECTED_DRIVES or ext in TABLE_EXTENSIONS:
        require_unsafe(state, f"{action} {path}")


def drive_login(path: str) -> Login:
    """The login that opens the drive of ``path`` (FILE for ``TNC:`` and relative paths)."""
    return DRIVE_LOGINS.get(wire_path(path)[:4].upper(), Login.FILE)


def _login_for(state: SessionState, path: str) -> Op[None]:
    yield from ensure_login(state, Login.FILE)
    login = drive_login(path)
    if login is not Login.FILE:
        yield from ensure_login(state, login)


def change_dir(state: SessionState, path: str) -> Op[None]:
    """``C_DC``: make ``path`` the current directory."""
    yield from _login_for(state, path)
    yield from command(ChangeDir(wire_path(path)), f"change directory to {path}")


def dir_info(state: SessionState, path: str | None = None) -> Op[DirectoryInfo]:
    """``R_DI`` of ``path`` (changes into it) or of the current directory."""
    if path is not None:
        yield from change_dir(state, path)
    else:
        yield from ensure_login(state, Login.FILE)
    reply = yield from ask(ReadDirInfo(), DirInfoReply, "read directory info")
    return reply.info


def _collect(first: Message | None, context: str) -> Op[list[FileEntry]]:
    entries: list[FileEntry] = []
    reply = first
    while not isinstance(reply, FileDone):
        if not isinstance(reply, DirReply):
            refuse(reply, context)
        entries.extend(reply.entries)
        reply = yield Ok()
    return entries


def list_dir(
    state: SessionState, path: str | None = None, *, multi: bool = True
) -> Op[list[FileInfo]]:
    """Entries of ``path`` (or the current directory), without ``.`` and ``..``.

    ``multi=True`` asks for all entries per telegram (``R_DR`` mode 1) and falls back to one
    entry per telegram (mode 0) when the control refuses.
    """
    info = yield from dir_info(state, path)
    folder = wire_path(info.path)
    if not folder.endswith("\\"):
        folder += "\\"
    context = f"list {folder}"
    reply = yield ReadDir(DirMode.MULTI if multi else DirMode.SINGLE)
    if multi and isinstance(reply, Refused):
        reply = yield ReadDir(DirMode.SINGLE)
    entries = yield from _collect(reply, context)
    out = []
    for e in entries:
        name = e.name.replace("/", "\\")
        if name in (".", "..") or name.endswith(":"):
            continue
        out.append(FileInfo.from_entry(e, folder + name, state.scheme))
    return out


def walk(state: SessionState, path: str, *, multi: bool = True) -> Op[list[FileInfo]]:
    """Every file and directory below ``path`` (each directory before its contents)."""
    found: list[FileInfo] = []
    pending = [wire_path(path)]
    while pending:
        folder = pending.pop(0)
        entries = yield from list_dir(state, folder, multi=multi)
        for entry in entries:
            found.append(entry)
            if entry.is_dir:
                pending.append(entry.path)
    return found


def drives(state: SessionState) -> Op[list[FileInfo]]:
    """``R_DR`` mode 2: the drives of the control."""
    yield from ensure_login(state, Login.FILE)
    reply = yield ReadDir(DirMode.DRIVES)
    entries = yield from _collect(reply, "list drives")
    return [FileInfo.from_entry(e, wire_path(e.name), state.scheme) for e in entries]


def file_info(state: SessionState, path: str) -> Op[FileInfo | None]:
    """``R_FI``: info on a file or directory; ``None`` if it does not exist."""
    yield from _login_for(state, path)
    p = wire_path(path)
    reply = yield ReadFileInfo(p)
    if isinstance(reply, Refused) and reply.code in _MISSING:
        return None
    entry = expect(reply, FileInfoReply, f"file info {path}").entry
    return FileInfo.from_entry(entry, p, state.scheme)


def make_dir(state: SessionState, path: str, *, parents: bool = True) -> Op[bool]:
    """Create directory ``path`` (and missing parents); ``False`` if it already existed."""
    yield from _login_for(state, path)
    p = wire_path(path).rstrip("\\")
    drive, sep, rest = p.partition(":")
    if not sep:
        raise InputError(f"{path!r}: give an absolute path such as TNC:\\nc_prog\\new")
    levels = [x for x in rest.split("\\") if x]
    if not levels:
        return False
    current = drive + ":\\"
    created = False
    for i, level in enumerate(levels):
        current += level + "\\"
        if not parents and i < len(levels) - 1:
            continue
        info = yield from file_info(state, current)
        if info is not None:
            if not info.is_dir:
                raise InputError(f"{current} exists and is not a directory")
            continue
        yield from command(MakeDir(current), f"make directory {current}")
        created = True
    return created


def remove_dir(state: SessionState, path: str, *, missing_ok: bool = False) -> Op[None]:
    """``C_DD``: delete an empty directory."""
    yield from _login_for(state, path)
    parent, _ = split_path(path)
    if parent:
        # TNC 3xx/6xx refuse to delete the current directory (a listing may have entered it).
        reply = yield ChangeDir(parent)
        if isinstance(reply, Refused) and reply.code in (*_MISSING, 47) and missing_ok:
            return
        expect(reply, Ok, f"remove directory {path}")
    reply = yield DeleteDir(wire_path(path))
    if isinstance(reply, Refused) and reply.code == 55 and missing_ok:
        return
    expect(reply, Ok, f"remove directory {path}")


def delete_file(state: SessionState, path: str, *, missing_ok: bool = False) -> Op[None]:
    """``C_FD``: delete a file (tables and PLC/SYS files only with safe mode off)."""
    guard_write(state, path, "deleting")
    yield from _login_for(state, path)
    reply = yield DeleteFile(wire_path(path))
    if isinstance(reply, Refused) and reply.code == 32 and missing_ok:
        return
    expect(reply, Ok, f"delete {path}")


def _source_and_target(state: SessionState, source: str, target: str) -> Op[tuple[str, str]]:
    # The control takes the source as a name in the current directory (docs/lsv2.md#file-commands).
    folder, name = split_path(source)
    if not name:
        raise InputError(f"{source!r} names no file")
    if folder:
        yield from change_dir(state, folder)
    dest = wire_path(target)
    if dest.endswith(("\\", ":")):
        dest += name
    return name, dest


def copy_file(state: SessionState, source: str, target: str) -> Op[None]:
    """``C_FC``: copy a file on the control (a target ending in ``\\`` keeps the name)."""
    guard_write(state, target, "copying onto")
    yield from _login_for(state, target)
    name, dest = yield from _source_and_target(state, source, target)
    yield from command(CopyFile(name, dest), f"copy {source} to {target}")


def move_file(state: SessionState, source: str, target: str) -> Op[None]:
    """``C_FR``: move or rename a file on the control."""
    guard_write(state, source, "moving")
    guard_write(state, target, "moving onto")
    yield from _login_for(state, target)
    name, dest = yield from _source_and_target(state, source, target)
    yield from command(MoveFile(name, dest), f"move {source} to {target}")


def ascii_blocks(data: bytes, limit: int) -> Iterator[bytes]:
    """Cut NUL-terminated lines into blocks of at most ``limit`` bytes, ending at line ends.

    A single line longer than ``limit`` has to be split; everything else ends at a NUL
    because controls reject ASCII blocks that stop mid-line (``T_BD`` 103).
    """
    start, n = 0, len(data)
    while start < n:
        end = min(start + limit, n)
        if end < n:
            cut = data.rfind(b"\0", start, end)
            if cut >= start:
                end = cut + 1
        yield data[start:end]
        start = end


def text_size(data: bytes, line_end: bytes = b"\r\n") -> int:
    """Size of text ``data`` on a control that stores each line end as ``line_end``.

    A text upload sends every CR LF or LF as one NUL (:func:`to_wire_ascii`) and the control
    writes its own line end for each NUL: what ``R_FI`` then reports for a file that arrived
    whole (docs/lsv2-serial.md, "Every text upload verified").
    """
    wire = to_wire_ascii(data)
    return len(wire) + wire.count(b"\0") * (len(line_end) - 1)


def _block_end(data: bytes, start: int, limit: int, *, text: bool) -> int:
    """End of the block that starts at ``start`` (see :func:`ascii_blocks`)."""
    end = min(start + limit, len(data))
    if text and end < len(data):
        cut = data.rfind(b"\0", start, end)
        if cut >= start:
            end = cut + 1
    return end


def binary_blocks(data: bytes, limit: int) -> Iterator[bytes]:
    """Cut ``data`` into blocks of ``limit`` bytes."""
    view = memoryview(data)
    for start in range(0, len(data), limit):
        yield bytes(view[start : start + limit])


def upload(
    state: SessionState,
    remote: str,
    data: bytes,
    *,
    binary: bool,
    overwrite: bool = True,
    progress: Progress | None = None,
) -> Op[None]:
    """``C_FL`` + ``S_FL`` blocks + ``T_FD``: store ``data`` as ``remote`` on the control.

    Tables and files on the PLC / SYS drives can only be written with safe mode off.
    """
    guard_write(state, remote, "writing")
    yield from _login_for(state, remote)
    path = wire_path(remote)
    mode = TransferMode.BINARY if binary else TransferMode.ASCII
    reply = yield SendFile(path, mode)
    if isinstance(reply, Refused) and reply.code == 34 and overwrite:
        yield from delete_file(state, path)
        reply = yield SendFile(path, mode)
    expect(reply, Ok, f"upload {remote}")
    payload = data if binary else to_wire_ascii(data)
    done, total = 0, len(data)
    if progress is not None:
        progress(0, total)
    context = f"upload {remote}"
    start = 0
    while start < len(payload):
        # the limit is asked per block: over serial it follows the line (TelegramSizer)
        end = _block_end(payload, start, state.upload_limit, text=not binary)
        block = payload[start:end]
        start = end
        reply = yield FileData(block)
        if type(reply) is not Ok:
            refuse(reply, context)
        if progress is not None:
            done += len(block)
            try:
                # Report local-file bytes: ASCII mode shrinks CR LF to NUL on the wire.
                progress(done * total // len(payload), total)
            except Exception:
                yield BlockDefect()  # the caller cancelled: abort the upload on the control
                raise
    reply = yield FileDone()
    if state.secure_send:
        expect(reply, Ok, f"finish upload {remote}")


def download(
    state: SessionState,
    remote: str,
    sink: Callable[[bytes], object],
    *,
    binary: bool,
    line_end: bytes = b"\r\n",
    progress: Progress | None = None,
) -> Op[int]:
    """``R_FL``: pass the file's blocks to ``sink``; returns the byte count delivered.

    In ASCII mode every NUL line end becomes ``line_end``. Each block is acknowledged before
    it is handed to ``sink`` (see :class:`~opendnc.lsv2.ops.base.Send`); if ``sink`` or
    ``progress`` raises, the control is stopped with ``T_BD`` at its next block and the error
    is re-raised.
    """
    yield from _login_for(state, remote)
    path = wire_path(remote)
    total: int | None = None
    if progress is not None:
        info = yield from file_info(state, path)
        total = info.size if info is not None else None
        progress(0, total)
    reply = yield ReadFile(path, TransferMode.BINARY if binary else TransferMode.ASCII)
    done = 0
    while not isinstance(reply, FileDone):
        if not isinstance(reply, FileData):
            refuse(reply, f"download {remote}")
        yield _SEND_NEXT  # the control prepares the next block while this one is stored
        try:
            data = reply.data if binary else from_wire_ascii(reply.data, line_end)
            sink(data)
            done += len(data)
            if progress is not None:
                progress(done, total)
        except Exception:
            # A local failure (disk full, cancelled): take the answer already under way, stop
            # the control's sequence if it is a block, so the session stays usable; re-raise.
            if isinstance((yield _RECEIVE), FileData):
                yield BlockDefect()
            raise
        reply = yield _RECEIVE
    return done
