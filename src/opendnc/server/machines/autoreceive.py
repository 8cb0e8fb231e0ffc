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

A file whose name and SHA-256 are those of a program this server sent to the machine is not
received: a folder that is both the way out and the way in (a machine's ``files`` folder,
docs/files.md) would otherwise echo every send into the inbox. It is remembered as seen, so
it is read once, not at every listing.
"""

from __future__ import annotations

import asyncio
import fnmatch
import hashlib
import logging
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from sqlalchemy import select
from sqlalchemy.orm import Session, sessionmaker

from opendnc.errors import ControlRefused
from opendnc.server.config.shop import ShopConfig
from opendnc.server.core.events import ProgramReceived
from opendnc.server.kinds.base import ReceiveFolder
from opendnc.server.kinds.connector import Connector, FolderSource
from opendnc.server.kinds.files import RemoteFile
from opendnc.server.kinds.registry import receive_folder_of
from opendnc.server.library import inbox
from opendnc.server.store import audit
from opendnc.server.store.models import AuditEntry
from opendnc.server.store.sends import sent_by_us

if TYPE_CHECKING:
    from opendnc.server.machines.state import Machines, MachineState

__all__ = ["AutoReceive", "FolderWatch", "Seen", "size_problem"]

log = logging.getLogger(__name__)


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

    def __init__(self, machine: str, receive: ReceiveFolder) -> None:
        self.machine = machine
        self.receive = receive
        self.folder = receive.folder
        self.pattern = receive.pattern.lower()
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


class AutoReceive:
    """Looks at the receive folder of every machine that has one (an LSV2 folder, a files
    folder), from that machine's task between two status polls (one listing never meets a
    transfer); a component."""

    name = "auto-receive"
    needs = ("machines", "database")

    def __init__(self, machines: Machines, sessions: sessionmaker[Session]) -> None:
        self.machines = machines
        self.sessions = sessions
        config: ShopConfig = machines.config
        self.inbox_folder = config.library.inbox
        found = ((m.name, receive_folder_of(m)) for m in config.machines)
        self.watches = {name: FolderWatch(name, r) for name, r in found if r is not None}
        self._polls: dict[str, int] = {}

    async def start(self) -> None:
        """Nothing to start: the machines' tasks call :meth:`look`."""

    async def stop(self) -> None:
        """Nothing to stop."""

    async def look(self, state: MachineState, connector: Connector) -> None:
        """Every ``receive_every`` calls, one look at the machine's receive folder."""
        watch = self.watches.get(state.config.name)
        if watch is None or not isinstance(connector, FolderSource):
            return
        polls = self._polls.get(watch.machine, 0)
        self._polls[watch.machine] = polls + 1
        if polls % watch.receive.every == 0:
            await self._look(state, connector, watch)

    async def _look(self, state: MachineState, connector: FolderSource, watch: FolderWatch) -> None:
        if not watch.loaded:
            await asyncio.to_thread(self._load_watch, watch)
        try:
            listing = await connector.list_files(watch.folder)
        except ControlRefused as exc:
            # No such folder (yet) on the control: the status polls go on regardless.
            state.last_error = f"receive folder {watch.folder}: {exc}"
            return
        for entry in watch.due(listing):
            try:
                data = await connector.fetch(entry.path)
            except ControlRefused as exc:
                log.info("%s: %s not read: %s", state.config.name, entry.path, exc)
                continue  # gone or locked since the listing; the next listing tells
            failed = size_problem(entry, data, entry)
            if failed is not None:
                # A size that disagrees: a second listing tells a file still being written
                # from a read that went wrong.
                again = {e.path.upper(): e for e in await connector.list_files(watch.folder)}
                failed = size_problem(entry, data, again.get(entry.path.upper()))
            if failed == "":
                continue  # it changed while we read it
            if failed is None and watch.known(entry, data):
                watch.mark(entry, data)  # touched, not changed
                continue
            if failed is None and await asyncio.to_thread(self._ours, watch.machine, entry, data):
                # One of our own sends, in a folder that is also the way in (a control's FTP
                # folder): no echo into the inbox.
                watch.mark(entry, data)
                continue
            await self._file_found(state, connector, watch, entry, data, failed or "")

    def _ours(self, machine: str, entry: RemoteFile, data: bytes) -> bool:
        digest = hashlib.sha256(data).hexdigest()
        with self.sessions() as session:
            return sent_by_us(session, machine, entry.name, digest)

    def _load_watch(self, watch: FolderWatch) -> None:
        with self.sessions() as session:
            watch.load(session)

    async def _file_found(
        self,
        state: MachineState,
        connector: FolderSource,
        watch: FolderWatch,
        entry: RemoteFile,
        data: bytes,
        failed: str,
    ) -> None:
        machine = state.config
        folder: Path = self.inbox_folder

        def keep() -> str:
            with self.sessions.begin() as session:
                row = inbox.store(
                    session,
                    machine.name,
                    data,
                    folder=folder,
                    failed=failed,
                    name=entry.name,
                    remote=watch.remote(entry),
                )
                return row.name

        name = await asyncio.to_thread(keep)
        watch.mark(entry, data)
        if failed:
            message = f"reception of {entry.path} failed: {failed}"
            state.last_error = message
        else:
            message = f"received {entry.path} into the inbox as {name}"
        bus = self.machines.bus
        bus.publish(ProgramReceived(machine.name, message))
        if failed or watch.receive.after != "delete":
            return
        # Only now that the reception is committed may the control's copy go.
        error = ""
        try:
            await connector.delete(entry.path)
        except ControlRefused as exc:
            error = str(exc)
            state.last_error = f"{entry.path} received but not deleted: {error}"

        def record() -> None:
            with self.sessions.begin() as session:
                audit.record(
                    session,
                    machine.name,
                    "program.receive.delete",
                    machine=machine.name,
                    program=name,
                    sha256=watch.seen[entry.path.upper()].sha256,
                    result="failed" if error else "ok",
                    path=entry.path,
                    error=error or None,
                )

        await asyncio.to_thread(record)
