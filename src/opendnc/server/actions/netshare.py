"""The hybrid net share as people look at it: its folders, the files in them beside the
library's released versions, and what it did lately (its audit rows)."""

from __future__ import annotations

from collections.abc import Iterable
from datetime import datetime

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from opendnc.errors import DncError
from opendnc.server.actions.base import Caller, Services, require
from opendnc.server.actions.models import (
    AuditOut,
    NetShareOut,
    ShareFileOut,
    ShareFolderOut,
    ShareMatch,
)
from opendnc.server.config.shop import NetShareConfig
from opendnc.server.core.folders import open_folder
from opendnc.server.kinds.registry import shares_of, spec_of
from opendnc.server.netshare.files import FolderListing, list_folder, nas_folder, share_label
from opendnc.server.netshare.share import ACTOR
from opendnc.server.store import audit
from opendnc.server.store.models import Program, ProgramState, ProgramVersion, Role

__all__ = ["ACTIVITY", "net_share"]

ACTIVITY = 30  # audit rows of the net share the page shows (the history has the rest)


def net_share(svc: Services, who: Caller, *, activity: int = ACTIVITY) -> NetShareOut:
    """The net share now: the NAS folder and each subscribed machine's share with their
    files (each beside the library), the archive, and its ``activity`` newest audit rows.
    Without a ``[netshare]`` table ``configured`` is False and ``candidates`` names the
    machines it could serve.

    The folders are listed here and now, as the scan lists them (a file's digest read once
    per size and time), so the page shows what the folders hold, not what was last done."""
    require(who, Role.VIEWER)
    config = svc.runner.config.netshare
    if config is None:
        shops = svc.runner.config.machines
        candidates = list(shares_of(shops))
        return NetShareOut(configured=False, candidates=candidates)
    nas = list_folder(nas_folder(config.path))
    shares: list[tuple[str, bool, FolderListing]] = []
    for name in config.machines:
        state = svc.machine(name)
        # the configuration subscribes only machines with a share (its kind says which)
        spec = spec_of(state.config).share(state.config)
        try:
            listing = list_folder(open_folder(spec))
        except DncError as exc:  # a mounted share that is not there
            listing = FolderListing(share_label(spec), error=str(exc))
        shares.append((name, state.online, listing))

    def load(session: Session) -> NetShareOut:
        names = {f.name for f in nas.files} | {f.name for _, _, s in shares for f in s.files}
        library = _Library(session, names)
        rows = audit.query(session, actor=ACTOR, limit=activity)
        last = audit.query(session, actor=ACTOR, action="netshare.archive_run", limit=1)
        return NetShareOut(
            configured=True,
            nas=_folder_out(None, None, nas, library),
            machines=[_folder_out(n, online, s, library) for n, online, s in shares],
            archive=str(config.archive),
            archive_at=_hhmm(config),
            archive_every=config.archive_every,
            last_archive=datetime.fromisoformat(str(last[0].detail["at"])) if last else None,
            interval=config.interval,
            collect=config.collect,
            activity=[AuditOut.of(r) for r in rows],
        )

    return svc.read(load)


def _hhmm(config: NetShareConfig) -> str | None:
    if config.archive_every is not None or config.archive_at is None:
        return None
    hour, minute = config.archive_at
    return f"{hour:02d}:{minute:02d}"


def _folder_out(
    machine: str | None, online: bool | None, listing: FolderListing, library: _Library
) -> ShareFolderOut:
    return ShareFolderOut(
        machine=machine,
        where=listing.where,
        online=online,
        error=listing.error,
        files=[library.beside(f.name, f.size, f.modified, f.sha256) for f in listing.files],
    )


class _Library:
    """The library's versions of the programs named like the files (one query)."""

    def __init__(self, session: Session, names: Iterable[str]) -> None:
        folded = sorted({n.lower() for n in names})
        self.versions: dict[str, list[ProgramVersion]] = {}
        self.program: dict[str, str] = {}
        if not folded:
            return
        stmt = (
            select(Program.name, ProgramVersion)
            .join(ProgramVersion, ProgramVersion.program_id == Program.id)
            .where(func.lower(Program.name).in_(folded))
            .order_by(ProgramVersion.number)
        )
        for program, version in session.execute(stmt):
            self.program[program.lower()] = program
            self.versions.setdefault(program.lower(), []).append(version)

    def beside(self, name: str, size: int, modified: datetime, sha256: str | None) -> ShareFileOut:
        """The file ``name`` as the library sees it."""
        versions = self.versions.get(name.lower(), [])
        released = [v for v in versions if v.state is ProgramState.RELEASED]
        same = [v for v in versions if v.sha256 == sha256] if sha256 else []
        match: ShareMatch
        if sha256 is None:
            match = "unreadable"
        elif not versions:
            match = "not in library"
        elif not released:
            match = "not released"
        elif released[-1].sha256 == sha256:
            match = "same"
        else:
            match = "differs"
        version = same[-1] if same else None
        return ShareFileOut(
            name=name,
            size=size,
            modified=modified,
            sha256=sha256,
            library=match,
            program=self.program.get(name.lower()),
            released=released[-1].number if released else None,
            version=version.number if version is not None else None,
            version_state=version.state if version is not None else None,
        )
