"""Sandboxed control file system: LSV2 drive paths mapped onto one host folder.

Layout of the root folder::

    ROOT/TNC/  ROOT/PLC/  ROOT/SYS/  ROOT/LOG/   one host folder per drive
    ROOT/.state/                                 machine parameters and other persistent state
    ROOT/.partial/                               uploads in progress (never visible on a drive)

Every wire path goes through :func:`parse_path` (pure: drive, collapsed separators, lexical
``..`` that may not climb above the drive, no control characters, no host drive tricks) and
then :meth:`ControlFs.host_path`, which looks each component up case-insensitively, keeps the
stored spelling and finally checks that the resolved host path is still inside the drive
folder (symlinks cannot lead out).
"""

from __future__ import annotations

import os
import shutil
import stat
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

from opendnc.atomicfile import create_temp
from opendnc.errors import ControlRefused
from opendnc.lsv2.constants import ErrorCode as E
from opendnc.lsv2.payloads import FileEntry
from opendnc.sim.tnc.profiles import Profile

# Characters no control accepts in a file name; ':' is only legal in the drive prefix.
_BAD_CHARS = frozenset('<>:"|?*') | {chr(c) for c in range(32)} | {"\x7f"}
MAX_PATH = 255
MAX_NAME = 128


# Refusals carry the LSV2 error code the control answers with (T_ER payload).
BAD_FNAME = E.T_ER_BAD_FNAME
NO_FILE = E.T_ER_NO_FILE
OPEN_FILE = E.T_ER_OPEN_FILE
FILE_EXISTS = E.T_ER_FILE_EXISTS
NO_DELETE = E.T_ER_NO_DELETE
NO_NEW_FILE = E.T_ER_NO_NEW_FILE
DEL_DIR = E.T_ER_DEL_DIR
NO_DIR = E.T_ER_NO_DIR
NO_RENAME = E.T_ER_NO_RENAME


@dataclass(frozen=True, slots=True)
class WirePath:
    """A normalised control path: drive (``TNC:``) and components."""

    drive: str
    parts: tuple[str, ...]

    def __str__(self) -> str:
        return self.drive + "\\" + "\\".join(self.parts)

    @property
    def is_root(self) -> bool:
        """True for a drive root such as ``TNC:\\``."""
        return not self.parts

    def as_dir(self) -> str:
        """Wire form with trailing separator, as ``S_DI`` reports it."""
        return str(self).rstrip("\\") + "\\"

    @property
    def parent(self) -> WirePath:
        """The containing directory (a root is its own parent)."""
        return WirePath(self.drive, self.parts[:-1])

    @property
    def name(self) -> str:
        """Last component ('' for a root)."""
        return self.parts[-1] if self.parts else ""


def parse_path(text: str, cwd: WirePath, drives: tuple[str, ...]) -> WirePath:
    """Normalise ``text`` (absolute or relative to ``cwd``) or raise ControlRefused(31).

    Accepts ``\\`` and ``/``, collapses repeated and trailing separators and resolves ``.`` and
    ``..`` lexically without ever leaving the drive.
    """
    if len(text) > MAX_PATH:
        raise ControlRefused(BAD_FNAME, "path too long")
    if any(ch in text for ch in ("\0",)):
        raise ControlRefused(BAD_FNAME, "NUL in path")
    norm = text.replace("/", "\\").strip(" ")
    drive = cwd.drive
    base: tuple[str, ...] = cwd.parts
    colon = norm.find(":")
    if colon >= 0:
        prefix = norm[: colon + 1].upper()
        if prefix not in drives:
            raise ControlRefused(BAD_FNAME, f"unknown drive {norm[: colon + 1]!r}")
        drive, norm, base = prefix, norm[colon + 1 :], ()
    elif norm.startswith("\\"):
        base = ()
    parts = list(base)
    for comp in norm.split("\\"):
        if comp in ("", "."):
            continue
        if comp == "..":
            if not parts:
                raise ControlRefused(BAD_FNAME, "path climbs above the drive root")
            parts.pop()
            continue
        if any(ch in _BAD_CHARS for ch in comp) or len(comp) > MAX_NAME:
            raise ControlRefused(BAD_FNAME, f"illegal file name {comp!r}")
        if comp.rstrip(" .") != comp:
            # Windows-style trailing dots/blanks alias other names: refuse them.
            raise ControlRefused(BAD_FNAME, f"illegal file name {comp!r}")
        parts.append(comp)
    return WirePath(drive, tuple(parts))


@dataclass(frozen=True, slots=True)
class Entry:
    """One file or directory as ``S_FI`` / ``S_DR`` report it."""

    name: str
    size: int
    mtime: int
    is_dir: bool
    read_only: bool
    selected: bool = False
    is_drive: bool = False

    def attributes(self, old_scheme: bool) -> int:
        """Attribute bits of docs/lsv2.md#file-entries in the family's scheme."""
        attr = 0x01
        if self.is_drive and not old_scheme:
            attr |= 0x10
        if self.is_dir:
            attr |= 0x40 if old_scheme else 0x20
        if self.read_only:
            attr |= 0x20 if old_scheme else 0x40
        if self.selected and not old_scheme:
            attr |= 0x80
        return attr

    def to_file_entry(self, old_scheme: bool) -> FileEntry:
        """The codec's entry (name made Latin-1 safe, numbers clamped to u32)."""
        name = self.name.encode("latin-1", "replace").decode("latin-1")
        return FileEntry(
            name=name,
            size=min(self.size, 0xFFFFFFFF),
            mtime=max(0, min(self.mtime, 0xFFFFFFFF)),
            attributes=self.attributes(old_scheme),
        )


class ControlFs:
    """The control's drives on the host, plus atomic uploads."""

    def __init__(self, root: Path, profile: Profile) -> None:
        self.root = root
        self.profile = profile
        self.drives = profile.drives
        self.partial_dir = root / ".partial"
        self.state_dir = root / ".state"
        for d in (self.partial_dir, self.state_dir):
            d.mkdir(parents=True, exist_ok=True)
        for drive in self.drives:
            self.drive_dir(drive).mkdir(parents=True, exist_ok=True)
        # Leftovers of a crash while uploading are never valid files.
        for stale in self.partial_dir.iterdir():
            if stale.is_file():
                stale.unlink()
        self._selected: set[str] = set()

    # -- path resolution ------------------------------------------------------------------
    def drive_dir(self, drive: str) -> Path:
        """Host folder of ``drive`` (``TNC:`` -> ROOT/TNC)."""
        return self.root / drive.rstrip(":").upper()

    def parse(self, text: str, cwd: WirePath) -> WirePath:
        """Normalise a wire path (see :func:`parse_path`)."""
        return parse_path(text, cwd, self.drives)

    def host_path(self, wp: WirePath) -> Path:
        """Host path of ``wp``, matching components case-insensitively; stays inside the drive."""
        base = self.drive_dir(wp.drive)
        current = base
        for comp in wp.parts:
            current = current / self._match(current, comp)
        resolved = current.resolve()
        if not resolved.is_relative_to(base.resolve()):
            raise ControlRefused(BAD_FNAME, "path leaves the drive")
        return current

    @staticmethod
    def _match(folder: Path, comp: str) -> str:
        if (folder / comp).exists():
            return comp
        low = comp.lower()
        try:
            for child in folder.iterdir():
                if child.name.lower() == low:
                    return child.name
        except (FileNotFoundError, NotADirectoryError):
            pass
        return comp

    def canonical(self, wp: WirePath) -> WirePath:
        """``wp`` with the stored spelling of each existing component."""
        host = self.host_path(wp)
        rel = host.relative_to(self.drive_dir(wp.drive))
        return WirePath(wp.drive, rel.parts)

    # -- queries --------------------------------------------------------------------------
    def entry(self, wp: WirePath, name: str | None = None) -> Entry:
        """Info about a file, directory or drive root; ControlRefused(32) when missing."""
        host = self.host_path(wp)
        try:
            st = host.stat()
        except OSError:
            raise ControlRefused(NO_FILE, f"{wp} does not exist") from None
        is_dir = stat.S_ISDIR(st.st_mode)
        label = name if name is not None else (str(self.canonical(wp)) if wp.parts else wp.drive)
        return Entry(
            name=label,
            size=0 if is_dir else st.st_size,
            mtime=int(st.st_mtime),
            is_dir=is_dir,
            read_only=not is_dir and not (st.st_mode & stat.S_IWUSR),
            selected=str(self.canonical(wp)).lower() in self._selected if wp.parts else False,
        )

    def listdir(self, wp: WirePath) -> list[Entry]:
        """Entries of a directory, sorted case-insensitively."""
        host = self.host_path(wp)
        if not host.is_dir():
            raise ControlRefused(NO_DIR, f"{wp} is not a directory")
        prefix = str(self.canonical(wp)).rstrip("\\").lower() + "\\"
        entries = []
        with os.scandir(host) as it:
            for item in it:
                try:
                    st = item.stat()
                except OSError:
                    continue  # vanished while listing
                is_dir = stat.S_ISDIR(st.st_mode)
                entries.append(
                    Entry(
                        name=item.name,
                        size=0 if is_dir else st.st_size,
                        mtime=int(st.st_mtime),
                        is_dir=is_dir,
                        read_only=not is_dir and not (st.st_mode & stat.S_IWUSR),
                        selected=(prefix + item.name.lower()) in self._selected,
                    )
                )
        return sorted(entries, key=lambda e: e.name.lower())

    def is_dir(self, wp: WirePath) -> bool:
        """True if ``wp`` names an existing directory."""
        return self.host_path(wp).is_dir()

    def free_bytes(self) -> int:
        """Free space of the host volume, saturated to u32."""
        return min(shutil.disk_usage(self.root).free, 0xFFFFFFFF)

    def open_read(self, wp: WirePath) -> BinaryIO:
        """The file opened for reading (downloads stream from it); refused with 32 if missing."""
        host = self.host_path(wp)
        if not host.is_file():
            raise ControlRefused(NO_FILE, f"{wp} does not exist")
        try:
            return host.open("rb")
        except OSError as exc:
            raise ControlRefused(OPEN_FILE, str(exc)) from None

    def read_bytes(self, wp: WirePath) -> bytes:
        """Whole file content; ControlRefused(32) if missing or a directory."""
        host = self.host_path(wp)
        if not host.is_file():
            raise ControlRefused(NO_FILE, f"{wp} does not exist")
        try:
            return host.read_bytes()
        except OSError as exc:
            raise ControlRefused(OPEN_FILE, str(exc)) from None

    # -- selection (active program cannot be deleted) ---------------------------------------
    def set_selected(self, paths: list[WirePath]) -> None:
        """Mark the programs the machine has selected (delete refused with 36)."""
        self._selected = {str(self.canonical(p)).lower() for p in paths}

    def _check_not_selected(self, wp: WirePath) -> None:
        if str(self.canonical(wp)).lower() in self._selected:
            raise ControlRefused(NO_DELETE, f"{wp} is selected for execution")

    # -- mutations ------------------------------------------------------------------------
    def mkdir(self, wp: WirePath) -> None:
        """Create one directory level."""
        if wp.is_root:
            raise ControlRefused(FILE_EXISTS, "drive root exists")
        host = self.host_path(wp)
        if host.exists():
            raise ControlRefused(FILE_EXISTS, f"{wp} exists")
        if not self.host_path(wp.parent).is_dir():
            raise ControlRefused(NO_DIR, f"{wp.parent} does not exist")
        try:
            host.mkdir()
        except OSError as exc:
            raise ControlRefused(NO_NEW_FILE, str(exc)) from None

    def rmdir(self, wp: WirePath) -> None:
        """Delete an empty directory."""
        host = self.host_path(wp)
        if wp.is_root:
            raise ControlRefused(DEL_DIR, "cannot delete a drive root")
        if not host.is_dir():
            raise ControlRefused(NO_DIR, f"{wp} does not exist")
        if any(host.iterdir()):
            raise ControlRefused(DEL_DIR, f"{wp} is not empty")
        host.rmdir()

    def delete(self, wp: WirePath) -> None:
        """Delete a file."""
        host = self.host_path(wp)
        if not host.is_file():
            raise ControlRefused(NO_FILE, f"{wp} does not exist")
        self._check_not_selected(wp)
        if not host.stat().st_mode & stat.S_IWUSR:
            raise ControlRefused(NO_DELETE, f"{wp} is write-protected")
        host.unlink()

    def copy(self, src: WirePath, dst: WirePath) -> None:
        """Copy a file on the control (target must not exist)."""
        s, d = self._src_dst(src, dst)
        self.write_atomic(dst, s.read_bytes(), overwrite=False)
        del d

    def move(self, src: WirePath, dst: WirePath) -> None:
        """Move or rename a file on the control."""
        s, d = self._src_dst(src, dst)
        self._check_not_selected(src)
        try:
            os.rename(s, d)
        except OSError as exc:
            raise ControlRefused(NO_RENAME, str(exc)) from None

    def _src_dst(self, src: WirePath, dst: WirePath) -> tuple[Path, Path]:
        s = self.host_path(src)
        if not s.is_file():
            raise ControlRefused(NO_FILE, f"{src} does not exist")
        d = self.host_path(dst)
        if d.exists():
            raise ControlRefused(FILE_EXISTS, f"{dst} exists")
        if not self.host_path(dst.parent).is_dir():
            raise ControlRefused(NO_FILE, f"{dst.parent} does not exist")
        return s, d

    def check_new_file(self, wp: WirePath, overwrite: bool = False) -> Path:
        """Validate an upload target before any data arrives; return the host path."""
        if wp.is_root:
            raise ControlRefused(BAD_FNAME, "no file name")
        host = self.host_path(wp)
        if host.is_dir():
            raise ControlRefused(FILE_EXISTS, f"{wp} is a directory")
        if host.exists() and not overwrite:
            raise ControlRefused(FILE_EXISTS, f"{wp} exists")
        if not self.host_path(wp.parent).is_dir():
            raise ControlRefused(NO_DIR, f"{wp.parent} does not exist")
        return host

    def open_partial(self) -> tuple[Path, int]:
        """A new hidden temp file for an upload (outside every drive)."""
        fd, path = create_temp(self.partial_dir, "up")
        return path, fd

    def commit_partial(self, partial: Path, wp: WirePath, overwrite: bool) -> Path:
        """Move a finished upload into place atomically; returns where it is on the host."""
        host = self.check_new_file(wp, overwrite)
        os.replace(partial, host)
        return host

    def write_atomic(self, wp: WirePath, data: bytes, overwrite: bool = True) -> None:
        """Write a whole file via a partial file and a rename."""
        self.check_new_file(wp, overwrite)
        partial, fd = self.open_partial()
        try:
            with os.fdopen(fd, "wb") as fh:
                fh.write(data)
            self.commit_partial(partial, wp, overwrite)
        finally:
            if partial.exists():
                partial.unlink()
