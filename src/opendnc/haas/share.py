"""Haas Net Share push: copy program files to an SMB share or to a mounted folder.

Targets:

* ``smb://[USER[:PASSWORD]@]HOST[:PORT]/SHARE[/PATH]`` — written with smbprotocol's
  ``smbclient`` module (SMB2/3, NTLM); credentials may also be passed as arguments.
* any local folder (e.g. where the control's Local Net Share is mounted).

Each file is written under a temporary name in the target folder and renamed over the final
name only once it is complete, so the control never sees a half-written program.
"""

from __future__ import annotations

import contextlib
import os
import uuid
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import unquote, urlsplit

from opendnc.atomicfile import AtomicWriter
from opendnc.errors import InputError, TransferError, TransportError

CHUNK = 64 * 1024
Progress = Callable[[int], None]
"""Called with the number of bytes just written."""


@dataclass(frozen=True, slots=True)
class ShareTarget:
    """Where to push: an SMB share folder or a local (mounted) folder."""

    host: str = ""
    port: int = 445
    share: str = ""
    folder: str = ""  # inside the share, "/"-separated
    username: str | None = None
    password: str | None = field(default=None, repr=False)  # never in a log or an error
    local: Path | None = None

    def unc(self, name: str = "") -> str:
        r"""UNC path ``\\host\share\folder\name`` of ``name`` in the target folder."""
        parts = [self.share, *[p for p in self.folder.split("/") if p]]
        if name:
            parts.append(name)
        return "\\\\" + self.host + "\\" + "\\".join(parts)

    def describe(self, name: str = "") -> str:
        """Readable location of ``name`` in the target."""
        if self.local is not None:
            return str(self.local / name)
        folder = "/".join(p for p in (self.share, self.folder.strip("/"), name) if p)
        return f"smb://{self.host}:{self.port}/{folder}"


def parse_target(spec: str) -> ShareTarget:
    """Parse ``smb://...`` or a folder path; :class:`InputError` names what is wrong."""
    if spec.lower().startswith("smb://"):
        parts = urlsplit(spec)
        segments = [unquote(s) for s in parts.path.split("/") if s]
        if not parts.hostname or not segments:
            raise InputError(f"bad share {spec!r}: use smb://HOST[:PORT]/SHARE[/PATH]")
        try:
            port = parts.port or 445
        except ValueError:
            raise InputError(f"bad port in {spec!r}") from None
        return ShareTarget(
            host=parts.hostname,
            port=port,
            share=segments[0],
            folder="/".join(segments[1:]),
            username=unquote(parts.username) if parts.username else None,
            password=unquote(parts.password) if parts.password else None,
        )
    folder = Path(spec).expanduser()
    if not folder.is_dir():
        raise InputError(f"share folder {spec!r} does not exist (mount the share first)")
    return ShareTarget(local=folder)


@dataclass(frozen=True, slots=True)
class PushResult:
    """One pushed file: source, where it went and its size."""

    source: Path
    destination: str
    size: int


def _check_sources(files: Sequence[str | os.PathLike[str]]) -> list[Path]:
    sources = [Path(f) for f in files]
    if not sources:
        raise InputError("no files to push")
    for source in sources:
        if not source.is_file():
            raise InputError(f"cannot push {source}: not a readable file")
    return sources


def push(
    files: Sequence[str | os.PathLike[str]],
    target: ShareTarget,
    *,
    username: str | None = None,
    password: str | None = None,
    progress: Progress | None = None,
    timeout: float = 30.0,
) -> list[PushResult]:
    """Copy ``files`` into ``target``; each arrives whole or not at all."""
    sources = _check_sources(files)
    if target.local is not None:
        return [_push_local(source, target.local, progress) for source in sources]
    return _push_smb(
        sources,
        target,
        username or target.username,
        password or target.password,
        progress,
        timeout,
    )


def _push_local(source: Path, folder: Path, progress: Progress | None) -> PushResult:
    final = folder / source.name
    try:
        writer = AtomicWriter(final, fsync=True)
    except OSError as exc:
        raise TransferError(f"cannot write into {folder}: {exc.strerror or exc}") from exc
    try:
        with writer, source.open("rb") as src:
            while chunk := src.read(CHUNK):
                writer.write(chunk)
                if progress:
                    progress(len(chunk))
    except OSError as exc:
        raise TransferError(f"pushing {source.name} to {folder} failed: {exc}") from exc
    return PushResult(source, str(final), final.stat().st_size)


def _push_smb(
    sources: list[Path],
    target: ShareTarget,
    username: str | None,
    password: str | None,
    progress: Progress | None,
    timeout: float,
) -> list[PushResult]:
    try:
        import smbclient
        from smbprotocol.exceptions import SMBException
    except ImportError as exc:  # the "haas" extra is optional
        raise InputError("SMB push needs smbprotocol: pip install 'opendnc[haas]'") from exc
    options = {"port": target.port, "username": username, "password": password}
    try:
        smbclient.register_session(
            target.host, username, password, port=target.port, connection_timeout=int(timeout)
        )
    except (SMBException, OSError, ValueError) as exc:
        raise TransportError(f"cannot open SMB session to {target.describe()}: {exc}") from exc
    results = []
    try:
        for source in sources:
            final = target.unc(source.name)
            tmp = target.unc(f".{source.name}.{uuid.uuid4().hex[:8]}.part")
            try:
                with (
                    smbclient.open_file(tmp, mode="wb", **options) as out,
                    source.open("rb") as src,
                ):
                    while chunk := src.read(CHUNK):
                        out.write(chunk)
                        if progress:
                            progress(len(chunk))
                smbclient.replace(tmp, final, **options)
            except (SMBException, OSError, ValueError) as exc:
                # the temp file may never have been created
                with contextlib.suppress(SMBException, OSError, ValueError):
                    smbclient.remove(tmp, **options)
                raise TransferError(
                    f"pushing {source.name} to {target.describe()} failed: {exc}"
                ) from exc
            results.append(PushResult(source, target.describe(source.name), source.stat().st_size))
    finally:
        with contextlib.suppress(SMBException, OSError, ValueError, KeyError):
            smbclient.delete_session(target.host, port=target.port)  # may already be gone
    return results
