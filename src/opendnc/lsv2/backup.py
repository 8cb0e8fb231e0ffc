"""Backup of a control's folder to a local folder, and sync of a local folder to the control.

Both run on top of the public :class:`~opendnc.lsv2.Client` API. The decision of *what* to
move is pure (:func:`plan_backup`, :func:`plan_sync`: listings in, a plan out), so the rules
are testable without a control and shared by any driver; :func:`backup` and :func:`sync`
carry the plan out with a blocking client.

* Backup is resumable: a file whose local copy has the remote size and modification time is
  skipped. Every file travels in binary mode into a temporary file beside its target, is
  checked against the remote size, gets the remote mtime and only then is renamed into place,
  so an interrupted run never leaves a partial file under a real name.
* Sync pushes what is missing on the control, differs in size, or was changed locally after
  the control's copy was written (LSV2 cannot set a remote mtime, so "remote older than
  local" is the change signal). Remote folders are created as needed.

One progress callback sees the bytes of the whole run, with the total known from the
listings before the first byte moves::

    with Client("192.168.56.101") as tnc:
        summary = backup(tnc, "TNC:/nc_prog", "backup/nc_prog", progress=print)
        print(summary.copied, summary.skipped, summary.failed, summary.bytes)
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

from opendnc.errors import ControlRefused, InputError, TransferError
from opendnc.lsv2.ops.files import FileInfo

__all__ = [
    "BackupProgress",
    "Failure",
    "FileJob",
    "Summary",
    "backup",
    "plan_backup",
    "plan_sync",
    "remote_relative",
    "sync",
]

BackupProgress = Callable[[int, int, str], None]
"""Progress callback: bytes done in the whole run, total bytes of the run, current file."""

_PER_FILE_ERRORS = (ControlRefused, InputError, TransferError)
"""Failures that concern one file; transport errors end the run (the link is gone)."""


class _FileClient(Protocol):
    """The part of :class:`~opendnc.lsv2.Client` that backup and sync use."""

    def walk(self, path: str = ..., *, multi: bool = ...) -> list[FileInfo]: ...
    def file_info(self, path: str) -> FileInfo | None: ...
    def make_dir(self, path: str, *, parents: bool = ...) -> bool: ...
    def download(
        self,
        remote: str,
        local: str | os.PathLike[str],
        *,
        binary: bool | None = ...,
        line_end: bytes = ...,
        progress: Callable[[int, int | None], None] | None = ...,
    ) -> int: ...
    def upload(
        self,
        local: str | os.PathLike[str],
        remote: str,
        *,
        binary: bool | None = ...,
        overwrite: bool = ...,
        progress: Callable[[int, int | None], None] | None = ...,
    ) -> int: ...


@dataclass(frozen=True, slots=True)
class FileJob:
    """One file to move: remote wire path, local path, size and remote mtime (epoch s)."""

    remote: str
    local: Path
    size: int
    mtime: float


@dataclass(frozen=True, slots=True)
class Failure:
    """A file that could not be moved, and why."""

    path: str
    reason: str


@dataclass
class Summary:
    """Outcome of a backup or sync run."""

    copied: list[str] = field(default_factory=list)
    """Files transferred (remote paths for backup, local-relative names for sync)."""
    skipped: list[str] = field(default_factory=list)
    """Files already up to date."""
    failed: list[Failure] = field(default_factory=list)
    bytes: int = 0
    """Bytes transferred."""
    folders_created: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        """True if no file failed."""
        return not self.failed


def _wire(path: str) -> str:
    p = path.replace("/", "\\")
    while "\\\\" in p:
        p = p.replace("\\\\", "\\")
    return p


def _join(folder: str, name: str) -> str:
    folder = _wire(folder)
    return folder + name if folder.endswith(("\\", ":")) else f"{folder}\\{name}"


def remote_relative(root: str, path: str) -> str:
    """``path`` relative to ``root`` with ``/`` separators (both wire paths, any case)."""
    base = _wire(root).rstrip("\\")
    full = _wire(path)
    if not full.lower().startswith(base.lower()):
        raise InputError(f"{path} is not below {root}")
    rest = full[len(base) :].lstrip("\\")
    parts = [p for p in rest.split("\\") if p]
    if not parts or any(p in (".", "..") for p in parts):
        raise InputError(f"unusable entry {path!r} below {root}")
    return "/".join(parts)


def _same(size: int, mtime: float, local: Path) -> bool:
    try:
        st = local.stat()
    except OSError:
        return False
    return st.st_size == size and int(st.st_mtime) == int(mtime)


def plan_backup(
    root: str, listing: Iterable[FileInfo], local_dir: Path
) -> tuple[list[FileJob], list[FileJob], list[Path]]:
    """Split a remote ``listing`` below ``root`` into (to copy, up to date, local folders).

    Drives, ``.``/``..`` and names that would escape ``local_dir`` are left out.
    """
    to_copy: list[FileJob] = []
    current: list[FileJob] = []
    folders: list[Path] = []
    for entry in listing:
        if entry.is_drive or entry.name in (".", ".."):
            continue
        try:
            rel = remote_relative(root, entry.path)
        except InputError:
            continue
        target = local_dir.joinpath(*rel.split("/"))
        if entry.is_dir:
            folders.append(target)
            continue
        job = FileJob(entry.path, target, entry.size, entry.modified.timestamp())
        (current if _same(job.size, job.mtime, target) else to_copy).append(job)
    return to_copy, current, folders


def plan_sync(
    local_dir: Path, remote_root: str, remote_listing: Iterable[FileInfo]
) -> tuple[list[FileJob], list[FileJob], list[str]]:
    """Compare ``local_dir`` with the control's listing of ``remote_root``.

    Returns (to upload, up to date, remote folders to create, parents first). A file is
    uploaded if it is missing remotely, its size differs, or the local file is newer than
    the control's copy.
    """
    remote: dict[str, FileInfo] = {}
    remote_dirs: set[str] = set()
    for entry in remote_listing:
        if entry.is_drive or entry.name in (".", ".."):
            continue
        try:
            rel = remote_relative(remote_root, entry.path).lower()
        except InputError:
            continue
        if entry.is_dir:
            remote_dirs.add(rel)
        else:
            remote[rel] = entry
    to_send: list[FileJob] = []
    current: list[FileJob] = []
    folders: list[str] = []
    for dirpath, dirnames, filenames in os.walk(local_dir):
        dirnames.sort()
        base = Path(dirpath)
        rel_dir = base.relative_to(local_dir).as_posix()
        if rel_dir != "." and rel_dir.lower() not in remote_dirs:
            folders.append(_join(remote_root, rel_dir.replace("/", "\\")))
        for name in sorted(filenames):
            if name.startswith(".") and name.endswith(".part"):
                continue  # our own temp files from an interrupted download
            path = base / name
            rel = name if rel_dir == "." else f"{rel_dir}/{name}"
            st = path.stat()
            job = FileJob(_join(remote_root, rel.replace("/", "\\")), path, st.st_size, st.st_mtime)
            have = remote.get(rel.lower())
            unchanged = (
                have is not None
                and have.size == st.st_size
                and have.modified.timestamp() >= int(st.st_mtime)
            )
            (current if unchanged else to_send).append(job)
    return to_send, current, folders


class _Meter:
    """Turns per-file progress into run-wide progress."""

    def __init__(self, total: int, callback: BackupProgress | None) -> None:
        self.total, self.callback, self.base = total, callback, 0

    def file(self, name: str) -> Callable[[int, int | None], None]:
        def report(done: int, _size: int | None) -> None:
            if self.callback is not None:
                self.callback(min(self.base + done, self.total), self.total, name)

        return report

    def finish(self, size: int) -> None:
        self.base += size


_TEMP_SUFFIX = ".backup.part"


def _temp_name(target: Path) -> Path:
    return target.with_name(f".{target.name}{_TEMP_SUFFIX}")


def _fetch(client: _FileClient, job: FileJob, meter: _Meter) -> int:
    """Download one file into a temp file, verify its size, set its mtime, rename it."""
    temp = _temp_name(job.local)
    try:
        got = client.download(job.remote, temp, binary=True, progress=meter.file(job.remote))
        if got != job.size:
            # The file may have changed on the control since the listing: ask again.
            now = client.file_info(job.remote)
            if now is None or now.size != got:
                raise TransferError(
                    f"backup {job.remote}: received {got} bytes, control lists {job.size}"
                )
        os.utime(temp, (job.mtime, job.mtime))
        os.replace(temp, job.local)
    except OSError as exc:
        raise InputError(f"cannot store {job.local}: {exc.strerror or exc}") from exc
    finally:
        if temp.exists():
            temp.unlink()
    return got


def backup(
    client: _FileClient,
    remote_dir: str,
    local_dir: str | os.PathLike[str],
    *,
    progress: BackupProgress | None = None,
) -> Summary:
    """Copy every file below ``remote_dir`` into ``local_dir``, skipping unchanged files.

    Per-file refusals are collected in :attr:`Summary.failed` and the run goes on; a lost
    connection raises (:class:`~opendnc.errors.TransportError`) after cleaning up the
    current file's temporary copy.
    """
    root = Path(local_dir)
    listing = client.walk(_wire(remote_dir))
    to_copy, current, folders = plan_backup(remote_dir, listing, root)
    summary = Summary(skipped=[j.remote for j in current])
    try:
        root.mkdir(parents=True, exist_ok=True)
        for folder in folders:
            folder.mkdir(parents=True, exist_ok=True)
        for folder in [root, *folders]:
            # leftovers of a run that was killed outright (no chance to clean up then)
            for stale in folder.glob(f".*{_TEMP_SUFFIX}*"):
                stale.unlink()
    except OSError as exc:
        raise InputError(f"cannot create {exc.filename}: {exc.strerror or exc}") from exc
    meter = _Meter(sum(j.size for j in to_copy), progress)
    for job in to_copy:
        try:
            job.local.parent.mkdir(parents=True, exist_ok=True)
            got = _fetch(client, job, meter)
        except _PER_FILE_ERRORS as exc:
            summary.failed.append(Failure(job.remote, str(exc)))
        except OSError as exc:
            summary.failed.append(Failure(job.remote, exc.strerror or str(exc)))
        else:
            summary.copied.append(job.remote)
            summary.bytes += got
        meter.finish(job.size)
    return summary


def sync(
    client: _FileClient,
    local_dir: str | os.PathLike[str],
    remote_dir: str,
    *,
    progress: BackupProgress | None = None,
) -> Summary:
    """Push the files of ``local_dir`` that changed to ``remote_dir`` (binary mode)."""
    root = Path(local_dir)
    if not root.is_dir():
        raise InputError(f"{root} is not a folder")
    target = _wire(remote_dir)
    exists = client.file_info(target) is not None
    listing = client.walk(target) if exists else []
    to_send, current, folders = plan_sync(root, target, listing)
    summary = Summary(skipped=[j.remote for j in current])
    if not exists:
        client.make_dir(target, parents=True)
        summary.folders_created.append(target)
    for folder in folders:
        if client.make_dir(folder, parents=True):
            summary.folders_created.append(folder)
    meter = _Meter(sum(j.size for j in to_send), progress)
    for job in to_send:
        try:
            sent = client.upload(
                job.local, job.remote, binary=True, progress=meter.file(job.remote)
            )
        except _PER_FILE_ERRORS as exc:
            summary.failed.append(Failure(job.remote, str(exc)))
        else:
            summary.copied.append(job.remote)
            summary.bytes += sent
        meter.finish(job.size)
    return summary
