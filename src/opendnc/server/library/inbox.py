"""Programs received from the controls: the inbox, and what a reception leads to.

A reception is named by the program's O-number (``O01234.nc``), else ``<machine>-<time>.nc``;
a file read from the control (a receive job, LSV2 auto-receive) keeps its own name when that
is a safe program name (``TNC:/nc_prog/1001.I`` arrives as ``1001.I``) and is compared with
the library's program of that name.
It is kept as a row (its bytes in the content-addressed blobs) and written to the inbox
folder, never over an existing file: a second ``O01234.nc`` becomes ``O01234.2.nc``. A person
accepts it (it becomes a new draft version of the program of that name) or discards it.
A reception that broke off is kept apart, in ``failed/`` with its reason, and never reaches the
library by itself.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from datetime import UTC, tzinfo
from pathlib import Path
from typing import Any

from sqlalchemy import select
from sqlalchemy.orm import Session

from opendnc.atomicfile import atomic_write
from opendnc.errors import InputError
from opendnc.server.core.errors import Conflict, NotFound
from opendnc.server.library import versions as library
from opendnc.server.store import audit
from opendnc.server.store.models import (
    Blob,
    ProgramVersion,
    Received,
    ReceivedState,
    utcnow,
)
from opendnc.xmodem.haas import program_header

__all__ = [
    "accept",
    "base_version",
    "diff_to_library",
    "discard",
    "get",
    "list_received",
    "store",
]


def _name_for(machine: str, data: bytes, given: str | None = None, zone: tzinfo = UTC) -> str:
    if given:
        try:
            return library.check_program_name(given)
        except InputError:
            pass  # an odd name on the control: named as a punch would be
    header = program_header(data)
    if header is not None:
        return f"O{header.number:05d}.nc"
    # on the shop's clock, as every time a person reads (a UTC stamp misled a CET shop)
    return f"{machine}-{utcnow().astimezone(zone):%Y%m%d-%H%M%S}.nc"


def _free_path(folder: Path, name: str) -> Path:
    # Never overwrite: O01234.nc, then O01234.2.nc, O01234.3.nc, ...
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / name
    stem, dot, suffix = name.rpartition(".")
    n = 1
    while path.exists():
        n += 1
        path = folder / (f"{stem}.{n}.{suffix}" if dot else f"{name}.{n}")
    return path


def store(
    session: Session,
    machine: str,
    data: bytes,
    *,
    folder: Path,
    failed: str = "",
    name: str | None = None,
    remote: dict[str, object] | None = None,
    zone: tzinfo = UTC,
) -> Received:
    """Keep a reception (``failed`` gives the reason a reception broke off).

    ``name`` is the file's own name where it had one (a file found on the control), and
    ``zone`` the shop's clock a name made of the time is on (a punch without an O-number), and
    ``remote`` what the control said of that file (path, size, time); the audit row keeps it,
    which is how auto-receive knows after a restart what it already took
    (:mod:`opendnc.server.machines.autoreceive`).
    """
    digest = hashlib.sha256(data).hexdigest()
    if session.get(Blob, digest) is None:
        session.add(Blob(sha256=digest, size=len(data), data=data))
    name = _name_for(machine, data, name, zone)
    target = _free_path(folder / "failed" if failed else folder, name)
    with atomic_write(target) as out:
        out.write(data)
    extra: dict[str, Any] = {"remote": remote} if remote is not None else {}
    row = Received(
        machine=machine,
        name=name,
        sha256=digest,
        size=len(data),
        state=ReceivedState.FAILED if failed else ReceivedState.NEW,
        reason=failed,
        path=str(target),
    )
    session.add(row)
    session.flush()
    audit.record(
        session,
        machine,
        "program.receive",
        machine=machine,
        program=name,
        sha256=digest,
        nbytes=len(data),
        result="failed" if failed else "ok",
        received_id=row.id,
        error=failed or None,
        **extra,
    )
    return row


def get(session: Session, received_id: int) -> Received:
    """One reception; :class:`NotFound` otherwise."""
    row = session.get(Received, received_id)
    if row is None:
        raise NotFound(f"nothing received with id {received_id}")
    return row


def content(session: Session, row: Received) -> bytes:
    """The received bytes."""
    blob = session.get(Blob, row.sha256)
    assert blob is not None  # foreign key
    return blob.data


def list_received(
    session: Session, states: Sequence[ReceivedState] = (ReceivedState.NEW,), limit: int = 200
) -> Sequence[Received]:
    """Receptions in the given states, newest first."""
    stmt = select(Received).order_by(Received.id.desc()).limit(max(1, min(limit, 10_000)))
    if states:
        stmt = stmt.where(Received.state.in_(list(states)))
    return session.scalars(stmt).all()


def accept(
    session: Session, received_id: int, *, actor: str, name: str | None = None
) -> ProgramVersion:
    """Make a reception a new draft version of ``name`` (default: its own name)."""
    row = get(session, received_id)
    if row.state is not ReceivedState.NEW:
        raise Conflict(f"reception {received_id} is {row.state.value}")
    version, _ = library.add_version(
        session,
        library.check_program_name(name or row.name),
        content(session, row),
        author=actor,
        comment=f"received from {row.machine}",
        source="inbox",
    )
    row.state = ReceivedState.ACCEPTED
    row.version_id = version.id
    audit.record(
        session,
        actor,
        "inbox.accept",
        machine=row.machine,
        program=version.program.name,
        sha256=row.sha256,
        received_id=row.id,
        version=version.number,
    )
    return version


def discard(session: Session, received_id: int, *, actor: str) -> Received:
    """Drop a reception from the inbox (its row and file stay for the record)."""
    row = get(session, received_id)
    if row.state is not ReceivedState.NEW:
        raise Conflict(f"reception {received_id} is {row.state.value}")
    row.state = ReceivedState.DISCARDED
    audit.record(
        session,
        actor,
        "inbox.discard",
        machine=row.machine,
        program=row.name,
        sha256=row.sha256,
        received_id=row.id,
    )
    return row


def base_version(session: Session, name: str) -> ProgramVersion | None:
    """The library version a reception named ``name`` is compared with: the released one,
    else the newest; None when the library has no program of that name."""
    try:
        return library.released_version(session, name) or library.get_version(session, name)
    except NotFound:
        return None


def diff_to_library(session: Session, received_id: int) -> list[str]:
    """Unified diff from the library version of the same name (:func:`base_version`) to the
    reception."""
    import difflib

    row = get(session, received_id)
    base = base_version(session, row.name)
    old = library.content(session, base).decode("latin-1") if base is not None else ""
    if base is None:
        label = "(not in library)"
    else:
        label = f"{row.name} v{base.number} ({base.state.value})"
    return list(
        difflib.unified_diff(
            old.splitlines(),
            content(session, row).decode("latin-1").splitlines(),
            label,
            f"{row.name} from {row.machine}",
            lineterm="",
        )
    )
