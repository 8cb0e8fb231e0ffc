"""Handlers for the file system: directory functions, file info and both transfer directions."""

from __future__ import annotations

import os
from collections.abc import Iterator
from typing import BinaryIO

from opendnc.errors import ControlRefused
from opendnc.lsv2.constants import ErrorCode as E
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
    ReadDir,
    ReadDirInfo,
    ReadFile,
    ReadFileInfo,
    Refused,
    SendFile,
)
from opendnc.lsv2.payloads import DirectoryInfo, FileEntry, from_wire_ascii, to_wire_ascii
from opendnc.sim.tnc.filesystem import Entry, WirePath
from opendnc.sim.tnc.session import OK, Priv, Session, Upload, block_defect, handler

MODE_BINARY = 0x01
MODE_MERGE = 0x02


def _entry(s: Session, entry: Entry) -> DirReply:
    return DirReply((entry.to_file_entry(s.control.profile.old_attributes),))


@handler(ReadDirInfo, Priv.FILE)
def directory_info(s: Session, m: ReadDirInfo) -> list[Message]:
    """R_DI: free bytes and the current directory with trailing separator."""
    path = s.cwd.as_dir().replace("\\", s.control.profile.dir_separator)
    return [DirInfoReply(DirectoryInfo(s.control.fs.free_bytes(), path))]


@handler(ReadDir, Priv.FILE)
def directory_list(s: Session, m: ReadDir) -> list[Message]:
    """R_DR mode: 0 one entry per S_DR, 1 packed entries, 2 drives."""
    mode = m.mode
    fs = s.control.fs
    if mode != 2:
        s.check_drive(s.cwd)  # e.g. FILEPLC dropped while the current directory is on PLC:
    if mode == 2:
        drives = [
            Entry(d, 0, int(fs.drive_dir(d).stat().st_mtime), True, False, is_drive=True)
            for d in fs.drives
        ]
        return s.start_sequence(_entry(s, e) for e in drives)
    if mode not in (0, 1):
        raise ControlRefused(E.T_ER_WRONG_PARA)
    entries = fs.listdir(s.cwd)
    if mode == 0:
        return s.start_sequence(_entry(s, e) for e in entries)
    return s.start_sequence(_packed(s, entries))


def _packed(s: Session, entries: list[Entry]) -> Iterator[Message]:
    old = s.control.profile.old_attributes
    block: list[FileEntry] = []
    size = 8
    for e in entries:
        fe = e.to_file_entry(old)
        need = 13 + len(fe.name)
        if block and size + need > s.buffer_size:
            yield DirReply(tuple(block))
            block, size = [], 8
        block.append(fe)
        size += need
    if block:
        yield DirReply(tuple(block))


@handler(ReadFileInfo, Priv.FILE)
def file_info(s: Session, m: ReadFileInfo) -> list[Message]:
    """R_FI path: file, directory or drive root."""
    wp = s.path(m.path)
    entry = s.control.fs.entry(wp)
    return [FileInfoReply(entry.to_file_entry(s.control.profile.old_attributes))]


@handler(ChangeDir, Priv.FILE)
def change_dir(s: Session, m: ChangeDir) -> list[Message]:
    """C_DC dir."""
    text = m.path
    try:
        wp = s.path(text)
        if not s.control.fs.is_dir(wp):
            raise ControlRefused(E.T_ER_NO_DIR)
    except ControlRefused:
        raise ControlRefused(E.T_ER_NO_DIR) from None
    s.cwd = s.control.fs.canonical(wp)
    return [OK]


@handler(MakeDir, Priv.FILE)
def make_dir(s: Session, m: MakeDir) -> list[Message]:
    """C_DM dir (one level)."""
    s.control.fs.mkdir(s.path(m.path))
    return [OK]


@handler(DeleteDir, Priv.FILE)
def delete_dir(s: Session, m: DeleteDir) -> list[Message]:
    """C_DD dir: empty directories only; the current one only where the family allows it."""
    fs = s.control.fs
    wp = s.path(m.path)
    if not fs.is_dir(wp):
        raise ControlRefused(E.T_ER_NO_DIR)
    inside_cwd = s.cwd.drive == wp.drive and [p.lower() for p in s.cwd.parts[: len(wp.parts)]] == [
        p.lower() for p in wp.parts
    ]
    if inside_cwd and not s.control.profile.delete_cwd_allowed:
        raise ControlRefused(E.T_ER_DEL_DIR, "directory in use")
    fs.rmdir(wp)
    if inside_cwd:
        s.cwd = wp.parent
    return [OK]


@handler(DeleteFile, Priv.FILE)
def delete_file(s: Session, m: DeleteFile) -> list[Message]:
    """C_FD file."""
    s.control.fs.delete(s.path(m.path))
    return [OK]


def _two_paths(s: Session, m: CopyFile | MoveFile) -> tuple[WirePath, WirePath]:
    if not m.source or not m.target:
        raise ControlRefused(E.T_ER_BAD_FNAME)
    return s.path(m.source), s.path(m.target)


@handler(CopyFile, Priv.FILE)
def copy_file(s: Session, m: CopyFile) -> list[Message]:
    """C_FC source target (source relative to the current directory)."""
    src, dst = _two_paths(s, m)
    s.control.fs.copy(src, dst)
    return [OK]


@handler(MoveFile, Priv.FILE)
def move_file(s: Session, m: MoveFile) -> list[Message]:
    """C_FR source target."""
    src, dst = _two_paths(s, m)
    s.control.fs.move(src, dst)
    return [OK]


# -- downloads --------------------------------------------------------------------------------
@handler(ReadFile, Priv.FILE)
def read_file(s: Session, m: ReadFile) -> list[Message]:
    """R_FL path [mode]: S_FL blocks within the buffer, then T_FD.

    The file is read block by block as the client's T_OKs pull them, as uploads are written:
    a connection that starts a large download and goes quiet holds one block, not the file.
    """
    mode = m.mode or 0
    handle = s.control.fs.open_read(s.path(m.path))
    return s.start_sequence(_file_blocks(handle, s.data_limit(), bool(mode & MODE_BINARY)))


def _file_blocks(handle: BinaryIO, step: int, binary: bool) -> Iterator[Message]:
    """S_FL blocks of ``step`` bytes, read (and ASCII-converted) only as they are asked for."""
    with handle:
        pending = b""  # converted bytes not sent yet: less than one block between reads
        cr_cut = False  # the last read ended in CR: it may be half of a CR LF
        sent = False
        while raw := handle.read(step):
            if not binary:
                if cr_cut:
                    raw = b"\r" + raw
                cr_cut = raw.endswith(b"\r")
                raw = to_wire_ascii(raw[:-1] if cr_cut else raw)
            pending += raw
            while len(pending) >= step:
                yield FileData(pending[:step])
                sent = True
                pending = pending[step:]
        if cr_cut:
            pending += b"\r"
        if pending or not sent:
            yield FileData(pending)  # pyLSV2 needs one block even for an empty file


# -- uploads ----------------------------------------------------------------------------------
@handler(SendFile, Priv.FILE)
def write_file(s: Session, m: SendFile) -> list[Message]:
    """C_FL path [mode]: open a hidden partial file; S_FL blocks follow."""
    mode = m.mode or 0
    wp = s.path(m.path)
    fs = s.control.fs
    merge = bool(mode & MODE_MERGE)
    host = fs.check_new_file(wp, overwrite=merge)
    partial, fd = fs.open_partial()
    if merge and host.exists():
        os.write(fd, host.read_bytes())
    s.upload = Upload(wp, partial, fd, bool(mode & MODE_BINARY), merge)
    return [OK]


@handler(FileData, Priv.FILE)
def file_block(s: Session, m: FileData) -> list[Message]:
    """One upload block."""
    up = s.upload
    if up is None:
        raise ControlRefused(E.T_ER_UNEXPECTED_TELE)
    data = m.data if up.binary else from_wire_ascii(m.data)
    try:
        up.add(data)
    except OSError:
        s.abort_upload()
        return [block_defect(E.T_BD_NO_FREE_SPACE)]
    return [OK]


@handler(FileDone, Priv.FILE)
def file_done(s: Session, m: FileDone) -> list[Message]:
    """End of an upload: rename into place; answer only with secure file send
    (docs/lsv2.md#upload)."""
    up = s.upload
    if up is None:
        return [Refused(E.T_ER_UNEXPECTED_TELE)] if s.secure_send else []
    s.upload = None
    try:
        try:
            up.flush()
        finally:
            os.close(up.fd)
        host = s.control.fs.commit_partial(up.partial, up.target, up.overwrite)
    except (OSError, ControlRefused) as exc:
        up.partial.unlink(missing_ok=True)
        code = exc.code if isinstance(exc, ControlRefused) else E.T_ER_NO_NEW_FILE
        return [Refused(code)] if s.secure_send else []
    s.control.log_event(f"File received: {up.target}")
    if s.control.on_received is not None:
        s.control.on_received(str(up.target), host)
    return [OK] if s.secure_send else []


@handler(BlockDefect, Priv.ANY)
def transfer_aborted(s: Session, m: BlockDefect) -> list[Message]:
    """Client aborts an upload: drop the partial file, no answer."""
    s.abort_upload()
    return []
