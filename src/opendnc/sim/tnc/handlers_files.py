"""Handlers for the file system: directory functions, file info and both transfer directions."""

from __future__ import annotations

import os
from collections.abc import Iterator

from opendnc.lsv2.constants import ErrorCode as E
from opendnc.lsv2.framing import Frame
from opendnc.lsv2.payloads import DirectoryInfo, read_cstr
from opendnc.sim.tnc.filesystem import Entry, FsError, WirePath
from opendnc.sim.tnc.session import (
    DONE,
    OK,
    Priv,
    Refuse,
    Session,
    Upload,
    block_defect,
    handler,
)

MODE_BINARY = 0x01
MODE_MERGE = 0x02


def _path_and_mode(payload: bytes) -> tuple[str, int]:
    """``cstr path`` + optional ``u8 mode`` (absent = ASCII)."""
    text, end = read_cstr(payload)
    mode = payload[end] if end < len(payload) else 0
    if not text:
        raise Refuse(E.T_ER_BAD_FNAME)
    return text, mode


def _entry_frame(s: Session, mnemonic: str, entry: Entry) -> Frame:
    return Frame(mnemonic, entry.encode(s.control.profile.old_attributes))


@handler("R_DI", Priv.FILE)
def directory_info(s: Session, f: Frame) -> list[Frame]:
    """R_DI: free bytes and the current directory with trailing separator."""
    info = DirectoryInfo(s.control.fs.free_bytes(), s.cwd.as_dir())
    return [Frame("S_DI", info.to_bytes())]


@handler("R_DR", Priv.FILE)
def directory_list(s: Session, f: Frame) -> list[Frame]:
    """R_DR mode: 0 one entry per S_DR, 1 packed entries, 2 drives (mode = last byte)."""
    mode = f.payload[-1] if f.payload else 0
    fs = s.control.fs
    if mode == 2:
        drives = [
            Entry(d, 0, int(fs.drive_dir(d).stat().st_mtime), True, False, is_drive=True)
            for d in fs.drives
        ]
        return s.start_sequence(_entry_frame(s, "S_DR", e) for e in drives)
    if mode not in (0, 1):
        raise Refuse(E.T_ER_WRONG_PARA)
    entries = fs.listdir(s.cwd)
    if mode == 0:
        return s.start_sequence(_entry_frame(s, "S_DR", e) for e in entries)
    return s.start_sequence(_packed(s, entries))


def _packed(s: Session, entries: list[Entry]) -> Iterator[Frame]:
    old = s.control.profile.old_attributes
    block = b""
    for e in entries:
        raw = e.encode(old)
        if block and 8 + len(block) + len(raw) > s.buffer_size:
            yield Frame("S_DR", block)
            block = b""
        block += raw
    if block:
        yield Frame("S_DR", block)


@handler("R_FI", Priv.FILE)
def file_info(s: Session, f: Frame) -> list[Frame]:
    """R_FI path: file, directory or drive root."""
    text = read_cstr(f.payload)[0]
    wp = s.path(text)
    return [_entry_frame(s, "S_FI", s.control.fs.entry(wp))]


@handler("C_DC", Priv.FILE)
def change_dir(s: Session, f: Frame) -> list[Frame]:
    """C_DC dir."""
    text = read_cstr(f.payload)[0]
    try:
        wp = s.path(text)
        if not s.control.fs.is_dir(wp):
            raise Refuse(E.T_ER_NO_DIR)
    except FsError:
        raise Refuse(E.T_ER_NO_DIR) from None
    s.cwd = s.control.fs.canonical(wp)
    return [OK]


@handler("C_DM", Priv.FILE)
def make_dir(s: Session, f: Frame) -> list[Frame]:
    """C_DM dir (one level)."""
    s.control.fs.mkdir(s.path(read_cstr(f.payload)[0]))
    return [OK]


@handler("C_DD", Priv.FILE)
def delete_dir(s: Session, f: Frame) -> list[Frame]:
    """C_DD dir: empty directories only; the current one only where the family allows it."""
    fs = s.control.fs
    wp = s.path(read_cstr(f.payload)[0])
    if not fs.is_dir(wp):
        raise Refuse(E.T_ER_NO_DIR)
    inside_cwd = s.cwd.drive == wp.drive and [p.lower() for p in s.cwd.parts[: len(wp.parts)]] == [
        p.lower() for p in wp.parts
    ]
    if inside_cwd and not s.control.profile.delete_cwd_allowed:
        raise Refuse(E.T_ER_DEL_DIR, "directory in use")
    fs.rmdir(wp)
    if inside_cwd:
        s.cwd = wp.parent
    return [OK]


@handler("C_FD", Priv.FILE)
def delete_file(s: Session, f: Frame) -> list[Frame]:
    """C_FD file."""
    s.control.fs.delete(s.path(read_cstr(f.payload)[0]))
    return [OK]


def _two_paths(s: Session, payload: bytes) -> tuple[WirePath, WirePath]:
    src, end = read_cstr(payload)
    dst = read_cstr(payload, end)[0] if end < len(payload) else ""
    if not src or not dst:
        raise Refuse(E.T_ER_BAD_FNAME)
    return s.path(src), s.path(dst)


@handler("C_FC", Priv.FILE)
def copy_file(s: Session, f: Frame) -> list[Frame]:
    """C_FC source target (source relative to the current directory)."""
    src, dst = _two_paths(s, f.payload)
    s.control.fs.copy(src, dst)
    return [OK]


@handler("C_FR", Priv.FILE)
def move_file(s: Session, f: Frame) -> list[Frame]:
    """C_FR source target."""
    src, dst = _two_paths(s, f.payload)
    s.control.fs.move(src, dst)
    return [OK]


# -- downloads --------------------------------------------------------------------------------
def to_wire_ascii(data: bytes) -> bytes:
    """ASCII mode: every line travels terminated by one NUL (CR LF / LF -> NUL)."""
    return data.replace(b"\r\n", b"\0").replace(b"\n", b"\0")


def from_wire_ascii(data: bytes) -> bytes:
    """ASCII upload: NUL line ends become CR LF; text already in CR LF stays as it is."""
    return data.replace(b"\0", b"\r\n")


@handler("R_FL", Priv.FILE)
def read_file(s: Session, f: Frame) -> list[Frame]:
    """R_FL path [mode]: S_FL blocks within the buffer, then T_FD."""
    text, mode = _path_and_mode(f.payload)
    wp = s.path(text)
    data = s.control.fs.read_bytes(wp)
    if not mode & MODE_BINARY:
        data = to_wire_ascii(data)
    step = s.data_limit()

    def blocks() -> Iterator[Frame]:
        if not data:
            yield Frame("S_FL", b"")  # pyLSV2 needs one block even for an empty file
            return
        for off in range(0, len(data), step):
            yield Frame("S_FL", data[off : off + step])

    return s.start_sequence(blocks())


# -- uploads ----------------------------------------------------------------------------------
@handler("C_FL", Priv.FILE)
def write_file(s: Session, f: Frame) -> list[Frame]:
    """C_FL path [mode]: open a hidden partial file; S_FL blocks follow."""
    text, mode = _path_and_mode(f.payload)
    wp = s.path(text)
    fs = s.control.fs
    merge = bool(mode & MODE_MERGE)
    host = fs.check_new_file(wp, overwrite=merge)
    partial, fd = fs.open_partial()
    if merge and host.exists():
        os.write(fd, host.read_bytes())
    s.upload = Upload(wp, partial, fd, bool(mode & MODE_BINARY), merge)
    return [OK]


@handler("S_FL", Priv.FILE)
def file_block(s: Session, f: Frame) -> list[Frame]:
    """One upload block."""
    up = s.upload
    if up is None:
        raise Refuse(E.T_ER_UNEXPECTED_TELE)
    data = f.payload if up.binary else from_wire_ascii(f.payload)
    try:
        os.write(up.fd, data)
    except OSError:
        s.abort_upload()
        return [block_defect(E.T_BD_NO_FREE_SPACE)]
    up.size += len(data)
    return [OK]


@handler("T_FD", Priv.FILE)
def file_done(s: Session, f: Frame) -> list[Frame]:
    """End of an upload: rename into place; answer only with secure file send (§6.2)."""
    up = s.upload
    if up is None:
        return [] if not s.secure_send else [block_defect(E.T_BD_BAD_FORMAT)]
    s.upload = None
    try:
        os.close(up.fd)
        s.control.fs.commit_partial(up.partial, up.target, up.overwrite)
    except (OSError, FsError) as exc:
        up.partial.unlink(missing_ok=True)
        code = exc.code if isinstance(exc, FsError) else E.T_ER_NO_NEW_FILE
        return [Frame("T_ER", bytes([1, code]))] if s.secure_send else []
    s.control.log_event(f"File received: {up.target}")
    return [OK] if s.secure_send else []


@handler("T_BD", Priv.ANY)
def transfer_aborted(s: Session, f: Frame) -> list[Frame]:
    """Client aborts an upload: drop the partial file, no answer."""
    s.abort_upload()
    return []


__all__ = ["DONE"]
