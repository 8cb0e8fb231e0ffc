"""The append-only audit trail: every transfer, approval, configuration change and login.

Rows are written in the same transaction as the change they describe, so a change and its
record are committed together or not at all.
"""

from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime
from typing import Any

from sqlalchemy import select
from sqlalchemy.orm import Session

from opendnc.server.store.models import AuditEntry

__all__ = ["query", "record"]


def record(
    session: Session,
    actor: str,
    action: str,
    *,
    machine: str | None = None,
    program: str | None = None,
    sha256: str | None = None,
    job_id: int | None = None,
    result: str = "ok",
    nbytes: int | None = None,
    **detail: Any,
) -> AuditEntry:
    """Add one audit row to ``session`` (committed with the caller's transaction)."""
    entry = AuditEntry(
        actor=actor,
        action=action,
        machine=machine,
        program=program,
        sha256=sha256,
        job_id=job_id,
        result=result,
        bytes=nbytes,
        detail=detail,
    )
    session.add(entry)
    return entry


def query(
    session: Session,
    *,
    machine: str | None = None,
    action: str | None = None,
    actor: str | None = None,
    program: str | None = None,
    since: datetime | None = None,
    until: datetime | None = None,
    limit: int = 200,
    before_id: int | None = None,
) -> Sequence[AuditEntry]:
    """Audit rows, newest first, filtered by whatever is given."""
    stmt = select(AuditEntry).order_by(AuditEntry.id.desc()).limit(max(1, min(limit, 10_000)))
    if machine is not None:
        stmt = stmt.where(AuditEntry.machine == machine)
    if action is not None:
        stmt = stmt.where(AuditEntry.action == action)
    if actor is not None:
        stmt = stmt.where(AuditEntry.actor == actor)
    if program is not None:
        stmt = stmt.where(AuditEntry.program == program)
    if since is not None:
        stmt = stmt.where(AuditEntry.at >= since)
    if until is not None:
        stmt = stmt.where(AuditEntry.at < until)
    if before_id is not None:
        stmt = stmt.where(AuditEntry.id < before_id)
    return session.scalars(stmt).all()
