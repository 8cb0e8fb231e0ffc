"""What the net share's folders hold now, as people look at it: each file's size, time and
SHA-256 (the dashboard's Net share page, :mod:`opendnc.server.actions.netshare`).

The folders are read as the scan reads them (:func:`opendnc.server.netshare.share.open_folder`: a
mounted folder or SMB, the same program files, the same size limit). A file's digest, which
says whether it is the library's released version, is read once per place, size and
modification time and then kept (:class:`Digests`): a page shown again reads no file that
did not change, only the listings.
"""

from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

from opendnc.errors import DncError
from opendnc.haas.share import ShareTarget, parse_target
from opendnc.server.core.folders import Folder, open_folder

__all__ = ["Digests", "FolderListing", "ShareFile", "list_folder", "nas_folder", "share_label"]


@dataclass(frozen=True)
class ShareFile:
    """One program file in a folder (``sha256`` None: it could not be read just now)."""

    name: str
    size: int
    modified: datetime  # UTC
    sha256: str | None


@dataclass(frozen=True)
class FolderListing:
    """A folder's program files by name, or why it could not be listed (``error``)."""

    where: str  # for people: an SMB folder without its login
    files: list[ShareFile] = field(default_factory=list)
    error: str = ""


class Digests:
    """SHA-256 of files by where they are, their size and modification time; the ones not
    asked for longest are forgotten past ``limit`` (pages are served from several threads)."""

    def __init__(self, limit: int = 4096) -> None:
        self.limit = limit
        self._known: OrderedDict[tuple[str, int, int], str] = OrderedDict()
        self._lock = threading.Lock()
        self.reads = 0  # files read to learn a digest (what the cache saves)

    def of(self, folder: Folder, name: str, size: int, modified_ns: int) -> str | None:
        """The digest of ``name`` in ``folder`` as listed; None if it cannot be read."""
        key = (folder.where(name), size, modified_ns)
        with self._lock:
            known = self._known.get(key)
            if known is not None:
                self._known.move_to_end(key)
                return known
        try:
            data = folder.read(name)
        except (DncError, OSError):
            return None  # removed or being replaced meanwhile: the next look reads it
        digest = hashlib.sha256(data).hexdigest()
        with self._lock:
            self.reads += 1
            # A file changed between the listing and the read is not filed under the
            # listing's size: the next look reads it again.
            if len(data) == size:
                self._known[key] = digest
                while len(self._known) > self.limit:
                    self._known.popitem(last=False)
        return digest


_DIGESTS = Digests()
_NAS: dict[Path | ShareTarget, Folder] = {}
_NAS_LOCK = threading.Lock()


def nas_folder(target: Path | ShareTarget) -> Folder:
    """The NAS folder, kept from page to page: over SMB it keeps one connection of its own
    (its login really checked, see :class:`opendnc.server.netshare.share.NetShare`) instead of
    opening one for every page shown."""
    with _NAS_LOCK:
        folder = _NAS.get(target)
        if folder is None:
            folder = _NAS[target] = open_folder(target, own_connections=True)
        return folder


def share_label(spec: str) -> str:
    """A machine's ``share`` setting for people: a folder as written, SMB without its login."""
    try:
        return parse_target(spec).describe()
    except DncError:
        # a local folder that is not there (the listing says so); an SMB location
        # always parses (the configuration checked it)
        return spec


def list_folder(folder: Folder, digests: Digests = _DIGESTS) -> FolderListing:
    """The program files of ``folder`` sorted by name, each with its digest."""
    try:
        entries = folder.entries()
    except DncError as exc:
        return FolderListing(folder.label, error=str(exc))
    files = [
        ShareFile(
            name,
            size,
            datetime.fromtimestamp(modified_ns / 1e9, UTC),
            digests.of(folder, name, size, modified_ns),
        )
        for name, (size, modified_ns) in sorted(entries.items(), key=lambda e: e[0].lower())
    ]
    return FolderListing(folder.label, files)
