"""An FTP folder on the control, reached with :mod:`ftplib` (the ``files`` capability's ``ftp``
mode, docs/files.md#ftp-folder-on-the-control).

Every call opens its own session and closes it: a control's FTP server drops idle sessions
and takes few at once, and a program load is rare beside a status poll. Passive mode by
default, so the control never has to connect back through a firewall. A program is stored
under a temporary name, its ``SIZE`` asked, read back and its SHA-256 compared, and only then
renamed to its real name: a copy the control did not keep whole never shows under the name an
operator would load. The calls block: the ``files`` connector runs them in a thread.
"""

from __future__ import annotations

import contextlib
import ftplib
import hashlib
import io
import secrets
from collections.abc import Iterator
from datetime import UTC, datetime

from opendnc.errors import ControlRefused, TransferError, TransportError
from opendnc.server.kinds.filedrop_config import FilesConfig
from opendnc.server.kinds.files import RemoteFile

__all__ = ["FtpDrop", "temp_name"]


def temp_name(name: str) -> str:
    """Where ``name`` is written first: hidden and ending ``.part``, so neither our own
    auto-receive nor the net share's folders take it for a program
    (:func:`opendnc.server.core.folders.is_program_name`)."""
    return f".{name}.{secrets.token_hex(3)}.part"


def _code(exc: ftplib.Error) -> int:
    text = str(exc)
    return int(text[:3]) if text[:3].isdigit() else 0


class FtpDrop:
    """One control's FTP folder: :meth:`put`, :meth:`read`, :meth:`listing`, :meth:`remove`."""

    def __init__(self, config: FilesConfig, machine: str) -> None:
        self.config = config
        self.machine = machine
        self.where = config.where()

    def _path(self, path: str) -> str:
        base = self.config.folder.rstrip("/")
        path = path.strip("/")
        if not base:
            return path
        return f"{base}/{path}" if path else base

    @contextlib.contextmanager
    def _session(self, what: str) -> Iterator[ftplib.FTP]:
        """A logged-in session; a refusal (a 5xx reply) is :class:`ControlRefused`, anything
        else on the way a :class:`TransportError`, both naming ``what`` and the machine."""
        c = self.config
        # latin-1: every byte of a name round-trips, whatever the control's code page
        ftp = ftplib.FTP(timeout=c.timeout, encoding="latin-1")
        context = f"{self.machine}: {what} ({self.where})"
        try:
            ftp.connect(c.host, c.port)
            ftp.login(c.user, c.password)
            ftp.set_pasv(c.passive)
            yield ftp
        except ftplib.error_perm as exc:
            raise ControlRefused(_code(exc), str(exc)[4:], context=context) from exc
        except (ftplib.Error, OSError, EOFError) as exc:
            raise TransportError(f"{context}: {exc or type(exc).__name__}") from exc
        finally:
            with contextlib.suppress(ftplib.Error, OSError, EOFError):
                ftp.quit()
            ftp.close()

    @staticmethod
    def _retrieve(ftp: ftplib.FTP, path: str) -> bytes:
        out = io.BytesIO()
        ftp.retrbinary(f"RETR {path}", out.write)
        return out.getvalue()

    def put(self, name: str, data: bytes) -> None:
        """Store ``data`` as ``name``: temporary name, size, read-back, rename."""
        final, temp = self._path(name), self._path(temp_name(name))
        with self._session(f"sending {name}") as ftp:
            ftp.storbinary(f"STOR {temp}", io.BytesIO(data))
            try:
                problem = self._check(ftp, temp, data)
                if problem:
                    raise TransferError(f"{self.machine}: {name} not sent: {problem}")
                self._rename(ftp, temp, final)
            except BaseException:
                with contextlib.suppress(ftplib.Error, OSError, EOFError):
                    ftp.delete(temp)  # never leave our copy behind, whole or not
                raise

    def _check(self, ftp: ftplib.FTP, temp: str, data: bytes) -> str:
        """Why the stored copy is not ``data`` (``""``: it is)."""
        try:
            size = ftp.size(temp)  # after STOR the type is binary (I), as SIZE needs
        except ftplib.error_perm:
            size = None  # no SIZE on this control: the read-back below still tells
        if size is not None and size != len(data):
            return f"the control stored {size} bytes of {len(data)}"
        back = self._retrieve(ftp, temp)
        if hashlib.sha256(back).digest() != hashlib.sha256(data).digest():
            return f"the copy read back differs ({len(back)} bytes, SHA-256 not the program's)"
        return ""

    @staticmethod
    def _rename(ftp: ftplib.FTP, temp: str, final: str) -> None:
        try:
            ftp.rename(temp, final)
        except ftplib.error_perm:
            # Some FTP servers (Windows' among them) refuse to rename onto an existing file:
            # the old copy goes only now, once the new one is whole beside it.
            ftp.delete(final)
            ftp.rename(temp, final)

    def read(self, path: str) -> bytes:
        """The bytes of ``path`` (relative to the folder)."""
        with self._session(f"reading {path}") as ftp:
            return self._retrieve(ftp, self._path(path))

    def holds(self, name: str, data: bytes) -> bool:
        """Whether ``name`` holds exactly ``data`` (absent: False)."""
        try:
            return hashlib.sha256(self.read(name)).digest() == hashlib.sha256(data).digest()
        except ControlRefused:
            return False

    def remove(self, path: str) -> None:
        """Delete ``path``."""
        with self._session(f"deleting {path}") as ftp:
            ftp.delete(self._path(path))

    def listing(self, folder: str) -> list[RemoteFile]:
        """The files of ``folder`` (relative to the folder): MLSD where the control has it,
        else NLST with SIZE and MDTM for each name."""
        where = self._path(folder)
        with self._session(f"listing {folder or '/'}") as ftp:
            try:
                return self._mlsd(ftp, where, folder)
            except ftplib.error_perm as exc:
                if _code(exc) not in (500, 501, 502, 504):
                    raise  # a refusal of the folder itself, not of the command
            return self._nlst(ftp, where, folder)

    @staticmethod
    def _entry(folder: str, name: str, size: int, modified: datetime) -> RemoteFile:
        path = f"{folder.strip('/')}/{name}" if folder.strip("/") else name
        return RemoteFile(name, path, size, modified, is_dir=False)

    def _mlsd(self, ftp: ftplib.FTP, where: str, folder: str) -> list[RemoteFile]:
        found = []
        for name, facts in ftp.mlsd(where or "", ["type", "size", "modify"]):
            if facts.get("type", "file") != "file":
                continue
            found.append(
                self._entry(folder, name, int(facts.get("size", 0)), _time(facts.get("modify")))
            )
        return found

    def _nlst(self, ftp: ftplib.FTP, where: str, folder: str) -> list[RemoteFile]:
        names = ftp.nlst(*([where] if where else []))  # a listing is sent in type A ...
        ftp.voidcmd("TYPE I")  # ... and SIZE counts bytes in type I only
        found = []
        for entry in names:
            name = entry.rsplit("/", 1)[-1]
            path = f"{where}/{name}" if where else name
            try:
                size = ftp.size(path)
            except ftplib.error_perm:
                continue  # a folder, or a file gone since the listing
            try:
                modified = _time(ftp.voidcmd(f"MDTM {path}")[4:])
            except ftplib.error_perm:
                modified = _time(None)
            found.append(self._entry(folder, name, size or 0, modified))
        return found


def _time(value: str | None) -> datetime:
    """An FTP time (``YYYYMMDDHHMMSS[.sss]``, UTC); the epoch where there is none."""
    try:
        return datetime.strptime((value or "")[:14], "%Y%m%d%H%M%S").replace(tzinfo=UTC)
    except ValueError:
        return datetime.fromtimestamp(0, UTC)
