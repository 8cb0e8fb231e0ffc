"""Auto-receive from a folder on a Heidenhain control (docs/server.md#auto-receive-from-a-tnc).

A machine with ``receive_folder`` has that folder listed over its LSV2 session every
``receive_every`` status polls. A file whose name matches ``receive_pattern`` is read once its
name, size and time are the same in two listings in a row (the operator or a CAM post may still
be writing it), and only if they differ from what was received of that path before. It is read
in binary mode (the bytes as the control holds them) and checked against the listed size: a file
that changed meanwhile is left for a later listing; one that still lists the old size is kept
as a failed reception with the reason. The bytes go into the inbox like a punch (never over an
earlier file, failed ones apart), under the file's own name. A file that was only touched (new
time, same bytes) makes no second reception.

What was received is rebuilt at start from the audit rows the inbox writes (``program.receive``
with ``remote``: path, size, time), so a file kept on the control (``after_receive = "keep"``,
the default) is not received again after a restart. With ``after_receive = "delete"`` the file
is deleted on the control after its reception is committed, never before.
"""

from __future__ import annotations

import fnmatch
import hashlib
from collections.abc import Iterable
from dataclasses import dataclass

from sqlalchemy import select
from sqlalchemy.orm import Session

from opendnc.server.config import MachineConfig
from opendnc.server.machine_files import RemoteFile
from opendnc.server.store.models import AuditEntry

__all__ = ["FolderWatch", "Seen", "size_problem"]


@dataclass(frozen=True)
class Seen:
    """A file as it was when it was last received."""

    size: int
    modified: str  # ISO time as the control listed it
    sha256: str


def _key(entry: RemoteFile) -> tuple[int, str]:
    return entry.size, entry.modified.isoformat()


class FolderWatch:
    """Which files of one machine's receive folder are due to be read (no I/O of its own)."""

    def __init__(self, machine: MachineConfig) -> None:
        self.machine = machine.name
        self.folder = machine.receive_folder
        self.pattern = machine.receive_pattern.lower()
        self.seen: dict[str, Seen] = {}  # remote path (upper case: TNC names ignore case)
        self.loaded = False
        self._last: dict[str, tuple[int, str]] = {}

    def load(self, session: Session) -> None:
        """Rebuild what was received from this machine's folder from the audit trail."""
        rows = session.scalars(
            select(AuditEntry)
            .where(AuditEntry.action == "program.receive", AuditEntry.machine == self.machine)
            .order_by(AuditEntry.id)
        )
        for row in rows:
            remote = row.detail.get("remote") if isinstance(row.detail, dict) else None
            if not isinstance(remote, dict) or not row.sha256:
                continue  # a punch, or a file collected from a share
            try:
                seen = Seen(int(remote["size"]), str(remote["modified"]), row.sha256)
                self.seen[str(remote["path"]).upper()] = seen
            except (KeyError, TypeError, ValueError):
                continue
        self.loaded = True

    def matches(self, entry: RemoteFile) -> bool:
        """A file (not a folder) whose name fits the pattern."""
        return not entry.is_dir and fnmatch.fnmatchcase(entry.name.lower(), self.pattern)

    def due(self, listing: Iterable[RemoteFile]) -> list[RemoteFile]:
        """The files to read now: unchanged since the previous listing, changed since their
        last reception (or never received)."""
        current = {e.path.upper(): e for e in listing if self.matches(e)}
        last, self._last = self._last, {path: _key(e) for path, e in current.items()}
        due = []
        for path, entry in sorted(current.items()):
            key = _key(entry)
            if last.get(path) != key:
                continue  # new or still changing: look again at the next listing
            seen = self.seen.get(path)
            if seen is not None and (seen.size, seen.modified) == key:
                continue
            due.append(entry)
        return due

    def known(self, entry: RemoteFile, data: bytes) -> bool:
        """True if ``data`` is what was received of this path last time (a touched file)."""
        seen = self.seen.get(entry.path.upper())
        return seen is not None and seen.sha256 == hashlib.sha256(data).hexdigest()

    def mark(self, entry: RemoteFile, data: bytes) -> None:
        """Remember ``entry`` as received with ``data``."""
        size, modified = _key(entry)
        self.seen[entry.path.upper()] = Seen(size, modified, hashlib.sha256(data).hexdigest())

    @staticmethod
    def remote(entry: RemoteFile) -> dict[str, object]:
        """What the audit row keeps of the file on the control."""
        size, modified = _key(entry)
        return {"path": entry.path, "size": size, "modified": modified}


def size_problem(entry: RemoteFile, data: bytes, again: RemoteFile | None) -> str | None:
    """Why a read of ``entry`` is not to be trusted: ``None`` if its size is the listed one,
    ``""`` if the file changed since the listing (try at a later listing), else the reason for a
    failed reception. ``again`` is the file in a listing made after the read."""
    if len(data) == entry.size:
        return None
    if again is None or _key(again) != _key(entry):
        return ""
    return f"read {len(data)} bytes of {entry.path}, the control lists {entry.size}"
