"""The folders the net share reads and a Haas NGC's connector writes: a local folder or an SMB
share (a machine's Local Net Share, or the NAS), behind one small protocol.

It may import the protocol layers (:mod:`opendnc.haas.share`) and nothing of the server."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any, Protocol

from opendnc.errors import InputError, TransportError
from opendnc.haas import share

__all__ = [
    "MAX_FILE",
    "Folder",
    "LocalFolder",
    "folder_at",
    "folder_for",
    "is_program_name",
    "open_folder",
]

MAX_FILE = 64 * 1024 * 1024  # larger files in a share are not programs to move around


def is_program_name(name: str) -> bool:
    # Hidden files, temporary copies (ours are ".NAME.xxxx.part") and editor backups are not
    # programs.
    if name.startswith(".") or name.endswith((".part", ".tmp", "~")) or len(name) > 255:
        return False
    return name.isprintable() and "/" not in name and "\\" not in name


class Folder(Protocol):
    """A folder the net share reads: the NAS, or a machine's share (local or SMB)."""

    label: str

    def where(self, name: str) -> str:
        """Where ``name`` is, for people (no login in it)."""
        ...

    def entries(self) -> dict[str, tuple[int, int]]:
        """Program files by name: (size, modification time); :class:`DncError` when away."""
        ...

    def read(self, name: str) -> bytes:
        """The content of ``name``."""
        ...

    def remove(self, name: str) -> None:
        """Delete ``name``."""
        ...


class LocalFolder:
    def __init__(self, path: Path) -> None:
        self.path = path
        self.label = str(path)

    def where(self, name: str) -> str:
        return str(self.path / name)

    def entries(self) -> dict[str, tuple[int, int]]:
        try:
            paths = list(self.path.iterdir())
        except OSError as exc:
            raise TransportError(f"cannot list {self.path}: {exc.strerror or exc}") from exc
        found = {}
        for path in paths:
            if is_program_name(path.name) and path.is_file() and not path.is_symlink():
                try:
                    st = path.stat()
                except OSError:
                    continue
                if st.st_size <= MAX_FILE:
                    found[path.name] = (st.st_size, st.st_mtime_ns)
        return found

    def read(self, name: str) -> bytes:
        return (self.path / name).read_bytes()

    def remove(self, name: str) -> None:
        (self.path / name).unlink()


_DIRECTORY, _REPARSE_POINT = 0x10, 0x400  # SMB file attribute bits


class _SmbFolder:
    """A folder over SMB (a machine's Local Net Share, or the NAS), through smbprotocol's
    smbclient.

    With ``own_connections`` the folder keeps its connections to itself instead of in
    smbclient's process-wide pool, which hands an existing session to anyone naming the same
    user on the same server without checking the password: the NAS's login is then really
    checked, and its connection stays open from scan to scan.
    """

    def __init__(self, target: share.ShareTarget, *, own_connections: bool = False) -> None:
        self.target = target
        self.label = target.describe()
        self._connections: dict[str, Any] | None = {} if own_connections else None

    def where(self, name: str) -> str:
        return self.target.describe(name)

    def _session(self) -> Any:
        try:
            import smbclient
        except ImportError as exc:  # the "haas" extra is optional
            raise InputError("SMB shares need smbprotocol: pip install 'opendnc[haas]'") from exc
        t = self.target
        try:
            smbclient.register_session(
                t.host,
                t.username,
                t.password,
                port=t.port,
                connection_timeout=10,
                connection_cache=self._connections,
            )
        except Exception as exc:  # smbprotocol raises its own tree and ValueError
            raise TransportError(f"cannot open SMB session to {self.label}: {exc}") from exc
        return smbclient

    def _options(self) -> dict[str, Any]:
        t = self.target
        options: dict[str, Any] = {"port": t.port, "username": t.username, "password": t.password}
        if self._connections is not None:
            options["connection_cache"] = self._connections
        return options

    def entries(self) -> dict[str, tuple[int, int]]:
        smbclient = self._session()
        found = {}
        with _smb_errors(f"cannot list {self.label}"):
            for entry in smbclient.scandir(self.target.unc(), **self._options()):
                # the listing carries size, time and attributes: no extra call per file
                info = entry.smb_info
                plain = not info.file_attributes & (_DIRECTORY | _REPARSE_POINT)
                if is_program_name(entry.name) and plain and info.end_of_file <= MAX_FILE:
                    written = int(info.last_write_time.timestamp() * 1e9)
                    found[entry.name] = (int(info.end_of_file), written)
        return found

    def read(self, name: str) -> bytes:
        smbclient = self._session()
        with (
            _smb_errors(f"cannot read {self.target.describe(name)}"),
            smbclient.open_file(self.target.unc(name), mode="rb", **self._options()) as f,
        ):
            data: bytes = f.read()
        return data

    def remove(self, name: str) -> None:
        smbclient = self._session()
        with _smb_errors(f"cannot remove {self.target.describe(name)}"):
            smbclient.remove(self.target.unc(name), **self._options())


@contextlib.contextmanager
def _smb_errors(what: str) -> Iterator[None]:
    """Any failure of an SMB call (smbprotocol raises its own tree, and ValueError) as a
    :class:`TransportError` that says ``what`` failed."""
    try:
        yield
    except Exception as exc:
        raise TransportError(f"{what}: {exc}") from exc


def folder_for(spec: str) -> Folder:
    return folder_at(share.parse_target(spec))  # InputError: a local folder that is not there


def open_folder(target: str | Path | share.ShareTarget, *, own_connections: bool = False) -> Folder:
    """A folder of the net share as the scan reads it: a machine's share (its ``share``
    setting: a folder or ``smb://``), or the NAS (``own_connections``: its SMB login checked
    on a connection of its own). :class:`InputError` for a local folder that is not there."""
    if isinstance(target, str):
        target = share.parse_target(target)
    return folder_at(target, own_connections=own_connections)


def folder_at(
    target: Path | share.ShareTarget, *, own_connections: bool = False
) -> LocalFolder | _SmbFolder:
    if isinstance(target, Path):
        return LocalFolder(target)
    if target.local is not None:
        return LocalFolder(target.local)
    return _SmbFolder(target, own_connections=own_connections)
