"""A folder the server reaches as files: a local (mounted) folder or an SMB share (the
``files`` capability's ``share`` mode), or the folder of a machine's account on this server's
FTP server (``ftp-server`` mode: the board fetches from it and stores into it by itself).

It reads and lists through the net share's folders (:mod:`opendnc.server.core.folders`) and
writes an SMB share with the net share's push (:func:`opendnc.haas.share.push`). A local
folder is written under a temporary name beside the target, read back and compared, and only
then renamed; an SMB copy arrives whole (the push renames it) and is read back after. The
calls block: the ``files`` connector runs them in a thread.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from datetime import UTC, datetime
from pathlib import Path

from opendnc.atomicfile import create_temp
from opendnc.errors import ControlRefused, DncError, InputError, TransferError
from opendnc.haas import share
from opendnc.server.core.folders import Folder, folder_at
from opendnc.server.kinds.files import RemoteFile

__all__ = ["FolderDrop"]

_NOT_FOUND = 2  # ENOENT, as the code of a refusal (a file or folder that is not there)


def _digest(data: bytes) -> bytes:
    return hashlib.sha256(data).digest()


class FolderDrop:
    """One machine's folder, local or SMB."""

    def __init__(self, spec: str, machine: str) -> None:
        self.spec = spec
        self.machine = machine
        self.where = spec

    def _target(self, folder: str = "") -> share.ShareTarget:
        target = share.parse_target(self.spec)  # InputError: a local folder that is not there
        self.where = target.describe()
        sub = folder.strip("/")
        if not sub:
            return target
        if target.local is not None:
            return share.ShareTarget(local=target.local / sub)
        return share.ShareTarget(
            host=target.host,
            port=target.port,
            share=target.share,
            folder="/".join(p for p in (target.folder.strip("/"), sub) if p),
            username=target.username,
            password=target.password,
        )

    def _split(self, path: str) -> tuple[Folder, str]:
        folder, _, name = path.strip("/").rpartition("/")
        if not name or name in (".", "..") or ".." in folder.split("/"):
            raise InputError(f"{path!r} names no file in {self.where}")
        return folder_at(self._target(folder)), name

    def put(self, name: str, data: bytes) -> None:
        """Store ``data`` as ``name``, read back before it takes the name (local) or after
        (SMB, whose push renames by itself)."""
        target = self._target()
        if target.local is not None:
            self._put_local(target.local, name, data)
            return
        with tempfile.TemporaryDirectory(prefix="opendnc-send-") as tmp:
            source = Path(tmp) / name
            source.write_bytes(data)
            share.push([source], target)
        folder = folder_at(target)
        if _digest(folder.read(name)) != _digest(data):
            folder.remove(name)  # not the program: no copy under its name
            raise TransferError(f"{self.machine}: {name} read back from {self.where} differs")

    def _put_local(self, folder: Path, name: str, data: bytes) -> None:
        try:
            fd, temp = create_temp(folder, name)
        except OSError as exc:
            raise TransferError(f"cannot write into {folder}: {exc.strerror or exc}") from exc
        try:
            with os.fdopen(fd, "wb") as out:
                out.write(data)
                out.flush()
                os.fsync(out.fileno())
            if _digest(temp.read_bytes()) != _digest(data):
                raise TransferError(f"{self.machine}: {name} read back from {folder} differs")
            os.replace(temp, folder / name)
        except OSError as exc:
            raise TransferError(f"writing {name} into {folder} failed: {exc}") from exc
        finally:
            temp.unlink(missing_ok=True)

    def read(self, path: str) -> bytes:
        """The bytes of ``path`` (relative to the folder)."""
        folder, name = self._split(path)
        try:
            return folder.read(name)
        except FileNotFoundError as exc:
            raise ControlRefused(_NOT_FOUND, "no such file", context=self.where) from exc
        except OSError as exc:
            raise ControlRefused(exc.errno or 0, exc.strerror or "", context=self.where) from exc

    def holds(self, name: str, data: bytes) -> bool:
        """Whether ``name`` holds exactly ``data`` (absent: False)."""
        try:
            return _digest(self.read(name)) == _digest(data)
        except ControlRefused:
            return False

    def remove(self, path: str) -> None:
        """Delete ``path``."""
        folder, name = self._split(path)
        try:
            folder.remove(name)
        except OSError as exc:
            raise ControlRefused(exc.errno or 0, exc.strerror or "", context=self.where) from exc

    def listing(self, folder: str) -> list[RemoteFile]:
        """The program files of ``folder`` (relative to the folder)."""
        try:
            entries = folder_at(self._target(folder)).entries()
        except (InputError, DncError) as exc:
            if isinstance(exc, InputError) or "No such file" in str(exc):
                raise ControlRefused(_NOT_FOUND, str(exc), context=self.where) from exc
            raise
        sub = folder.strip("/")
        return [
            RemoteFile(
                name,
                f"{sub}/{name}" if sub else name,
                size,
                datetime.fromtimestamp(modified_ns / 1e9, UTC),
                is_dir=False,
            )
            for name, (size, modified_ns) in sorted(entries.items())
        ]
