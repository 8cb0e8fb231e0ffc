"""Keys and the audit trail: who may do what, and what was done."""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Sequence

from fastapi.responses import Response
from sqlalchemy.orm import Session

from opendnc.errors import InputError
from opendnc.server.access import auth
from opendnc.server.actions.base import Caller, Services, require
from opendnc.server.actions.models import AuditOut, ClusterOut, KeyOut, RevokedOut
from opendnc.server.machines.leases import view_in
from opendnc.server.store import audit
from opendnc.server.store.models import Role

__all__ = ["AUDIT_COLUMNS", "audit_csv_response", "create_key", "list_audit", "revoke_key"]

AUDIT_COLUMNS = [
    "id",
    "at",
    "actor",
    "action",
    "machine",
    "program",
    "sha256",
    "job_id",
    "result",
    "bytes",
    "detail",
]


def create_key(svc: Services, who: Caller, user: str, role: str, label: str = "") -> KeyOut:
    """A key (shown once) for ``user``; a missing user is created with that role."""
    require(who, Role.ADMIN)
    wanted = Role.parse(role)
    if label.strip().lower() == auth.SESSION_LABEL:
        raise InputError(f"the label {auth.SESSION_LABEL!r} is the dashboard's own")

    def make(session: Session) -> KeyOut:
        row, key = auth.create_key(
            session, user, wanted, label=label, actor=who.name, create_user_role=wanted
        )
        return KeyOut(id=row.id, key=key, user=user, role=wanted.name.lower())

    return svc.write(make)


def revoke_key(svc: Services, who: Caller, key_id: int) -> RevokedOut:
    """Revoke a key for good (twice is harmless)."""
    require(who, Role.ADMIN)
    svc.write(lambda s: auth.revoke_key(s, key_id, actor=who.name))
    svc.keys.forget(key_id)  # at once, not when the cache's seconds are up
    return RevokedOut(id=key_id, revoked=True)


def list_audit(
    svc: Services,
    who: Caller,
    *,
    machine: str | None = None,
    action: str | None = None,
    actor: str | None = None,
    program: str | None = None,
    limit: int = 200,
    before: int | None = None,
) -> list[AuditOut]:
    """The audit trail, newest first, filtered by whatever is given."""
    require(who, Role.VIEWER)

    def load(session: Session) -> list[AuditOut]:
        rows = audit.query(
            session,
            machine=machine,
            action=action,
            actor=actor,
            program=program,
            limit=limit,
            before_id=before,
        )
        return [AuditOut.of(a) for a in rows]

    return svc.read(load)


def audit_csv_response(rows: Sequence[AuditOut]) -> Response:
    """``rows`` as a CSV download (``detail`` as JSON in one column)."""
    out = io.StringIO()
    writer = csv.DictWriter(out, AUDIT_COLUMNS)
    writer.writeheader()
    for row in rows:
        data = row.model_dump(mode="json")
        writer.writerow({**data, "detail": json.dumps(data["detail"], sort_keys=True)})
    return Response(
        out.getvalue(),
        media_type="text/csv",
        headers={"Content-Disposition": 'attachment; filename="audit.csv"'},
    )


def cluster_status(svc: Services, who: Caller) -> ClusterOut:
    """The servers sharing this database, their heartbeats and leases (any server answers
    the same; a single server on SQLite lists none)."""
    require(who, Role.VIEWER)
    return svc.read(lambda session: ClusterOut.of(view_in(session)))
