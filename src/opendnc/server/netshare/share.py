"""The hybrid net share: one NAS folder fanned out to the machines' own shares.

A shop drops programs into one folder on its NAS; every subscribed Haas NGC gets a copy in
its local share (Local Net Share, or a folder the control mounts), so the operator loads it
from the control's device manager without touching the NAS; at the end of the day the NAS
folder is archived; programs written on the machines come back to the server's inbox
(docs/haas.md#net-share). One scan every ``interval`` seconds:

1. **push**: a NAS file that stopped changing (same size and time in two scans) and whose
   content a machine has not had yet is copied into that machine's share, whole or not at
   all (:func:`opendnc.haas.share.push`; a local folder or ``smb://``), if the queue's policy
   lets it go there (the ``gate``: a ``released_only`` machine takes released library
   versions only, a program check's errors block): a refusal is audited with its reason. A
   failed copy is tried again at the next scan, but audited only when its outcome changes
   (the first failure, a new reason, the success after): a share that stays away, or a file
   that keeps failing, is one row, not one a scan. A name no share can take (longer than
   :data:`MAX_PUSH_NAME` bytes: the copy's temporary name would pass the 255 bytes a file
   name may have) is not tried at all: one ``skipped`` row per machine and content.
2. **collect** (``collect = true``): a file in a machine's share that the server
   did not put there (neither the push nor a send job of its own: :func:`sent_by_us`), or
   that changed since (the operator edited it), is filed in the inbox by
   :func:`opendnc.server.library.inbox.store`, once per content. What a share held when the server
   first saw it is taken as the machine's history, not as new work (one ``netshare.baseline``
   row lists it).
3. **archive** (daily at ``archive_at`` on the shop's clock, or every ``archive_every``
   seconds, once no NAS file is still being written): the NAS files, pushed first, move
   into ``archive/YYYY-MM-DD/`` (never overwriting) and the copies the server pushed are
   removed from the shares if they still hold exactly the pushed bytes; an edited copy stays
   (and is collected).

A machine's share is a local (mounted) folder or ``smb://[USER:PASSWORD@]HOST[:PORT]/SHARE/PATH``
(read, listed and cleaned with smbprotocol, the library :mod:`opendnc.haas.share` pushes with).
The NAS is either too: over SMB it is listed, read and emptied (at the archive) the same way;
its archive goes to the server's local archive folder. Every folder is polled, one listing per
scan: SMB has no change notifications the server could rely on. A label, an audit row or a log
line names an SMB folder without its login.

Every action is an audit row (``netshare.push``, ``netshare.collect``, ``netshare.baseline``,
``netshare.archive``, ``netshare.archive_run``) and an event of kind ``netshare``. What the
server pushed, collected and when it last archived is rebuilt from those rows at start, so a
restart neither pushes again nor collects twice, and an archive missed while the server was
down runs when it comes back. The clock is injectable (tests do not wait for 18:00).
"""

from __future__ import annotations

import asyncio
import hashlib
import logging
import os
import re
import shutil
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime, timedelta, tzinfo
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sqlalchemy import or_, select
from sqlalchemy.orm import Session, sessionmaker

from opendnc.atomicfile import AtomicWriter
from opendnc.errors import DncError
from opendnc.haas import share
from opendnc.server.core.components import RunsTask
from opendnc.server.core.events import EventBus, NetshareChanged
from opendnc.server.core.folders import Folder, LocalFolder, folder_at, folder_for
from opendnc.server.kinds.base import SharedMachine
from opendnc.server.library import inbox
from opendnc.server.store import audit
from opendnc.server.store.models import AuditEntry
from opendnc.server.store.sends import sent_by_us

if TYPE_CHECKING:
    # for types only: the configuration loads the kinds, and a Haas NGC's connector reads
    # its share through this module's folders
    from opendnc.server.config.shop import NetShareConfig

__all__ = ["NetShare", "ScanReport", "local_now"]

log = logging.getLogger(__name__)

ACTOR = "netshare"
# A push writes ".NAME.xxxxxxxx.part" first (15 bytes more than the name) and renames it: a
# longer name fails on every file system and share that caps a name at 255 bytes, which is
# nearly all of them.
MAX_PUSH_NAME = 240


def local_now(zone: tzinfo | None = None) -> datetime:
    """Now on the shop's clock (``[server] timezone``, which ``archive_at`` is on; without
    one, this computer's zone)."""
    return datetime.now(zone) if zone is not None else datetime.now().astimezone()


@dataclass
class ScanReport:
    """What one scan did (file names; ``failed`` holds ``(machine, name, reason)``)."""

    pushed: list[tuple[str, str]] = field(default_factory=list)  # (machine, name)
    collected: list[tuple[str, str]] = field(default_factory=list)
    archived: list[str] = field(default_factory=list)
    failed: list[tuple[str, str, str]] = field(default_factory=list)
    refused: list[tuple[str, str, str]] = field(default_factory=list)  # by the policy


ShareGate = Callable[[SharedMachine, str, bytes], str | None]
"""Whether a NAS file (name, content) may go into a machine's share: None, or why not
(:func:`opendnc.server.actions.policy.share_gate`: the decision a send gets, from
:func:`opendnc.server.actions.policy.authorize`). Every net share has one: a copy into a
share is a program reaching a machine."""


def _reason(error: str) -> str:
    # A push's error may name its temporary copy, whose middle is random each time; without
    # it, the same failure reads the same at every scan.
    return _TEMP_NAME.sub(".part", error)


_TEMP_NAME = re.compile(r"\.[0-9A-Za-z_]{8}\.part\b")


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


class _Stable:
    """Files that stopped changing: the same size and modification time in two scans."""

    def __init__(self) -> None:
        self._last: dict[str, dict[str, tuple[int, int]]] = {}

    def names(self, folder: Folder, entries: dict[str, tuple[int, int]]) -> list[str]:
        last = self._last.get(folder.label, {})
        self._last[folder.label] = entries
        return sorted(name for name, seen in entries.items() if last.get(name) == seen)


class NetShare(RunsTask):
    """The net share task (a component running :meth:`run`); :meth:`scan` for one pass."""

    name = "netshare"
    needs: tuple[str, ...] = ("database", "machines", "actions")  # its gate is the actions' policy

    def __init__(
        self,
        config: NetShareConfig,
        machines: dict[str, SharedMachine],
        inbox_folder: Path,
        sessions: sessionmaker[Session],
        bus: EventBus | None = None,
        *,
        gate: ShareGate,
        clock: Callable[[], datetime] = local_now,
    ) -> None:
        self.config = config
        self.machines = {name: machines[name] for name in config.machines}
        self.inbox_folder = inbox_folder
        self.sessions = sessions
        self.bus = bus
        self.clock = clock
        self.gate = gate
        self.refused: dict[tuple[str, str], tuple[str, str]] = {}  # -> (sha256, why), audited
        self.pushed: dict[tuple[str, str], str] = {}  # (machine, name) -> sha256 put there
        # (machine, name) -> (sha256, reason) of a push that failed or was skipped: the same
        # outcome again writes no row
        self.failing: dict[tuple[str, str], tuple[str, str]] = {}
        self.collected: dict[tuple[str, str], str] = {}  # (machine, name) -> sha256 taken
        self.baselined: set[str] = set()  # machines whose share history is recorded
        self.last_archive: datetime | None = None
        self._stable = _Stable()
        self._loaded = False
        self.nas = folder_at(config.path, own_connections=True)
        self._nas_away = ""  # why the NAS could not be listed (logged once per reason)

    # ------------------------------------------------------------------ state
    def load(self) -> None:
        """Rebuild what was pushed, collected and archived from the audit trail."""
        # from scratch: in a cluster another server may have run the share meanwhile
        self.pushed.clear()
        self.collected.clear()
        self.baselined.clear()
        self.failing.clear()
        with self.sessions() as session:
            rows = session.scalars(
                select(AuditEntry)
                .where(AuditEntry.actor == ACTOR)
                .where(or_(AuditEntry.result == "ok", AuditEntry.action == "netshare.push"))
                .order_by(AuditEntry.id)
            ).all()
            for row in rows:
                key = (row.machine or "", row.program or "")
                if row.action == "netshare.push" and row.result != "ok":
                    # the last outcome of a push that has not succeeded since
                    reason = _reason(str(row.detail.get("error") or ""))
                    self.failing[key] = (row.sha256 or "", reason)
                elif row.action == "netshare.push" and row.sha256:
                    self.pushed[key] = row.sha256
                    self.failing.pop(key, None)
                elif row.action == "netshare.collect" and row.sha256:
                    self.collected[key] = row.sha256
                elif row.action == "netshare.baseline" and row.machine:
                    self.baselined.add(row.machine)
                    for name, digest in dict(row.detail.get("files", {})).items():
                        self.collected[(row.machine, str(name))] = str(digest)
                elif row.action == "netshare.archive":
                    for machine in row.detail.get("removed_from", []):
                        self.pushed.pop((str(machine), row.program or ""), None)
                elif row.action == "netshare.archive_run":
                    self.last_archive = datetime.fromisoformat(str(row.detail["at"]))
        if self.last_archive is None:
            # Never archived: the first archive is the next one due, not one for the past.
            self.last_archive = self.clock()
        self._loaded = True

    # ------------------------------------------------------------------ the task
    async def run(self) -> None:
        """Scan every ``interval`` seconds until cancelled; one failed scan (the database
        away at start included: the first scan loads the state) stops nothing."""
        self._loaded = False  # each start reads the trail: a cluster's share moves between servers
        while True:
            try:
                await self.scan()
            except asyncio.CancelledError:
                raise
            except Exception:
                log.exception("net share scan failed")
            await asyncio.sleep(self.config.interval)

    async def scan(self) -> ScanReport:
        """One pass: push, collect, archive when due (file and database work in a thread)."""
        return await asyncio.to_thread(self.scan_sync)

    def scan_sync(self) -> ScanReport:
        """:meth:`scan` on the calling thread."""
        if not self._loaded:
            self.load()
        report = ScanReport()
        folder = self.nas
        try:
            entries = folder.entries()
            nas_here = True
            self._nas_away = ""
        except DncError as exc:
            entries, nas_here = {}, False  # the NAS is away: nothing to push or archive now
            if str(exc) != self._nas_away:
                self._nas_away = str(exc)
                log.warning("net share: the NAS is away: %s", exc)
        nas = self._stable.names(folder, entries)
        contents = {}
        for name in nas:
            try:
                contents[name] = folder.read(name)
            except (DncError, OSError):
                continue
        for name, data in contents.items():
            for machine in self.machines.values():
                self._push(machine, name, data, report)
        if self.config.collect:
            for machine in self.machines.values():
                try:
                    self._collect(machine, report)
                except DncError as exc:  # a share that is away; the push reports it too
                    log.info("%s: cannot collect from the share: %s", machine.name, exc)
        # Archive only a quiet folder: a file still being written moves at the next scan.
        if nas_here and len(nas) == len(entries) and self._archive_due():
            self._archive(nas, report)
        return report

    # ------------------------------------------------------------------ push
    def _push(self, machine: SharedMachine, name: str, data: bytes, report: ScanReport) -> None:
        digest = _sha(data)
        key = (machine.name, name)
        if self.pushed.get(key) == digest:
            return
        why = self.gate(machine, name, data)
        if why is not None:
            # asked again every scan (a release may come), audited once per content and reason
            report.refused.append((machine.name, name, why))
            if self.refused.get(key) != (digest, why):
                self.refused[key] = (digest, why)
                with self.sessions.begin() as session:
                    audit.record(
                        session,
                        ACTOR,
                        "netshare.push",
                        machine=machine.name,
                        program=name,
                        sha256=digest,
                        nbytes=len(data),
                        result="refused",
                        source=self.nas.where(name),
                        error=why,
                    )
                self._publish("push", machine.name, name, error=why)
            return
        self.refused.pop(key, None)
        error = ""
        destination = ""
        skipped = len(name.encode("utf-8", "surrogateescape")) > MAX_PUSH_NAME
        if skipped:
            error = (
                f"not pushed: the name is longer than {MAX_PUSH_NAME} bytes, more than a "
                "share's temporary copy of it can hold; rename it on the NAS"
            )
        else:
            try:
                target = share.parse_target(machine.share)
                with tempfile.TemporaryDirectory(prefix="opendnc-netshare-") as tmp:
                    source = Path(tmp) / name
                    source.write_bytes(data)
                    destination = share.push([source], target)[0].destination
            except (DncError, OSError) as exc:
                error = str(exc) or type(exc).__name__
        if error:
            report.failed.append((machine.name, name, error))
            if self.failing.get(key) == (digest, _reason(error)):
                return  # the same outcome as the last scan's: audited then
        with self.sessions.begin() as session:
            audit.record(
                session,
                ACTOR,
                "netshare.push",
                machine=machine.name,
                program=name,
                sha256=digest,
                nbytes=len(data),
                result=("skipped" if skipped else "failed") if error else "ok",
                source=self.nas.where(name),
                destination=destination,
                error=error or None,
            )
        if error:
            self.failing[key] = (digest, _reason(error))
            self._publish("push", machine.name, name, error=error)
            return
        self.failing.pop(key, None)
        self.pushed[key] = digest
        report.pushed.append((machine.name, name))
        self._publish("push", machine.name, name)

    # ------------------------------------------------------------------ collect
    def _collect(self, machine: SharedMachine, report: ScanReport) -> None:
        folder = folder_for(machine.share)
        entries = folder.entries()
        found: dict[str, bytes] = {}
        for name in self._stable.names(folder, entries):
            try:
                found[name] = folder.read(name)
            except (DncError, OSError):
                continue
        if machine.name not in self.baselined:
            # The first look at a share: what it holds already is the machine's history.
            # Wait until every file in it has stopped changing.
            if len(found) == len(entries):
                self._baseline(machine, found)
            return
        for name, data in found.items():
            digest = _sha(data)
            key = (machine.name, name)
            if self.pushed.get(key) == digest or self.collected.get(key) == digest:
                continue
            with self.sessions.begin() as session:
                if sent_by_us(session, machine.name, name, digest):
                    # a send job of ours wrote it into the share: never a reception
                    self.collected[key] = digest
                    continue
                row = inbox.store(session, machine.name, data, folder=self.inbox_folder)
                audit.record(
                    session,
                    ACTOR,
                    "netshare.collect",
                    machine=machine.name,
                    program=name,
                    sha256=digest,
                    nbytes=len(data),
                    source=f"{folder.label}/{name}",
                    received_id=row.id,
                    inbox_name=row.name,
                )
            self.collected[key] = digest
            report.collected.append((machine.name, name))
            self._publish("collect", machine.name, name)

    def _baseline(self, machine: SharedMachine, found: dict[str, bytes]) -> None:
        files = {name: _sha(data) for name, data in found.items()}
        with self.sessions.begin() as session:
            audit.record(session, ACTOR, "netshare.baseline", machine=machine.name, files=files)
        for name, digest in files.items():
            self.collected[(machine.name, name)] = digest
        self.baselined.add(machine.name)

    # ------------------------------------------------------------------ archive
    def _archive_due(self) -> bool:
        now = self.clock()
        last = self.last_archive
        if last is None:
            return False
        every = self.config.archive_every
        if every is not None:
            return (now - last).total_seconds() >= every
        if self.config.archive_at is None:
            return False
        hour, minute = self.config.archive_at
        mark = now.replace(hour=hour, minute=minute, second=0, microsecond=0)
        if mark > now:
            mark -= timedelta(days=1)
        return last < mark

    def _archive(self, nas: list[str], report: ScanReport) -> None:
        now = self.clock()
        day = self.config.archive / f"{now:%Y-%m-%d}"
        moved: list[str] = []
        for name in nas:
            try:
                data = self.nas.read(name)
            except (DncError, OSError):
                continue
            digest = _sha(data)
            removed = self._remove_pushed_copies(name)
            error = ""
            try:
                day.mkdir(parents=True, exist_ok=True)
                destination = _free_path(day, name)
                self._move_out(name, data, destination)
            except OSError as exc:
                error = exc.strerror or str(exc)
                destination = day / name
            except DncError as exc:
                error = str(exc)
                destination = day / name
            with self.sessions.begin() as session:
                audit.record(
                    session,
                    ACTOR,
                    "netshare.archive",
                    program=name,
                    sha256=digest,
                    nbytes=len(data),
                    result="failed" if error else "ok",
                    source=self.nas.where(name),
                    destination=str(destination),
                    removed_from=removed,
                    error=error or None,
                )
            if error:
                report.failed.append(("", name, error))
                continue
            moved.append(name)
            report.archived.append(name)
        with self.sessions.begin() as session:
            audit.record(
                session,
                ACTOR,
                "netshare.archive_run",
                at=now.isoformat(),
                folder=str(day),
                files=moved,
            )
        self.last_archive = now
        self._publish("archive", "", "", files=moved, folder=str(day))

    def _move_out(self, name: str, data: bytes, destination: Path) -> None:
        """Move a NAS file into the archive: a rename on a mounted NAS; over SMB the bytes
        just read are written (whole or not at all), then the NAS copy is removed."""
        if isinstance(self.nas, LocalFolder):
            shutil.move(str(self.nas.path / name), str(destination))
            return
        with AtomicWriter(destination, fsync=True) as out:
            out.write(data)
        try:
            self.nas.remove(name)
        except DncError:
            destination.unlink()  # still on the NAS: archived at the next run, not twice
            raise

    def _remove_pushed_copies(self, name: str) -> list[str]:
        """Remove ``name`` from the shares that still hold exactly what was pushed."""
        removed = []
        for machine in self.machines.values():
            digest = self.pushed.get((machine.name, name))
            if digest is None:
                continue
            try:
                folder = folder_for(machine.share)
                if _sha(folder.read(name)) == digest:
                    folder.remove(name)
                    removed.append(machine.name)
                    del self.pushed[(machine.name, name)]
            except (DncError, OSError):
                continue  # away, gone already, or edited and then removed: nothing to do
        return removed

    # ------------------------------------------------------------------ events
    def _publish(self, action: str, machine: str, name: str, **extra: Any) -> None:
        if self.bus is not None:
            self.bus.publish(NetshareChanged(action, machine, name, extra))


def _free_path(folder: Path, name: str) -> Path:
    # Never overwrite in the archive: O01234.nc, then O01234.2.nc, ...
    path = folder / name
    stem, dot, suffix = name.rpartition(".")
    n = 1
    while path.exists() or os.path.lexists(path):
        n += 1
        path = folder / (f"{stem}.{n}.{suffix}" if dot else f"{name}.{n}")
    return path
