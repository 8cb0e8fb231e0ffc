"""``/api/machines/{name}/dprnt``: the DPRNT lines the server captured, as JSON or CSV.

Kept beside :mod:`opendnc.server.api` (it uses the same key check and database session) so the
capture can be read without touching the main route table. ``since`` is the id of the last
line a client has seen: polling with it returns only newer lines, in order. The dashboard's
DPRNT console reads through :func:`recent_lines` and downloads through :func:`csv_response`.
"""

from __future__ import annotations

import csv
import io
from collections.abc import Sequence
from typing import Any

from fastapi import APIRouter, Request
from fastapi.responses import Response
from sqlalchemy import select
from sqlalchemy.orm import Session

from opendnc.errors import InputError
from opendnc.server import deps
from opendnc.server.api import Db, Viewer
from opendnc.server.dprnt_capture import line_json
from opendnc.server.edge import ApiRoute
from opendnc.server.errors import NotFound
from opendnc.server.store.models import DprntLine

__all__ = ["CSV_COLUMNS", "csv_response", "lines_after", "recent_lines", "router"]

CSV_COLUMNS = ["id", "at", "machine", "line", "fields", "complete"]
MAX_LIMIT = 10_000

router = APIRouter(prefix="/api", route_class=ApiRoute)


def lines_after(session: Session, machine: str, since: int, limit: int) -> list[dict[str, Any]]:
    """``machine``'s lines after id ``since``, oldest first, at most ``limit``."""
    rows = session.scalars(
        select(DprntLine)
        .where(DprntLine.machine == machine, DprntLine.id > since)
        .order_by(DprntLine.id)
        .limit(limit)
    ).all()
    return [line_json(row) for row in rows]


def recent_lines(session: Session, machine: str, limit: int) -> list[dict[str, Any]]:
    """``machine``'s newest ``limit`` lines, oldest first (what a console shows)."""
    rows = session.scalars(
        select(DprntLine)
        .where(DprntLine.machine == machine)
        .order_by(DprntLine.id.desc())
        .limit(limit)
    ).all()
    return [line_json(row) for row in reversed(rows)]


def csv_response(machine: str, lines: Sequence[dict[str, Any]]) -> Response:
    """``lines`` as a CSV download (RFC 4180: quoted where a value holds a comma, a quote or a
    line end; quotes doubled; CR LF between records)."""
    out = io.StringIO()
    writer = csv.writer(out)
    writer.writerow(CSV_COLUMNS)
    for line in lines:
        fields = " ".join(
            f"{f['label']}={f['value']:g}" if f["label"] else f"{f['value']:g}"
            for f in line["fields"]
        )
        complete = "yes" if line["complete"] else "no"
        writer.writerow([line["id"], line["at"], machine, line["line"], fields, complete])
    return Response(
        out.getvalue(),
        media_type="text/csv",
        headers={"Content-Disposition": f'attachment; filename="{machine}-dprnt.csv"'},
    )


@router.get("/machines/{name}/dprnt", response_model=None)
def machine_dprnt(
    request: Request,
    name: str,
    db: Db,
    _who: Viewer,
    since: int = 0,
    limit: int = 1000,
    format: str = "json",
) -> list[dict[str, Any]] | Response:
    """Lines after id ``since``, oldest first (at most ``limit``); ``format=csv`` for a file."""
    if name not in deps.machines(request).machines:
        raise NotFound(f"no machine named {name!r}")
    if format not in ("json", "csv"):
        raise InputError("format is json or csv")
    if since < 0 or not 1 <= limit <= MAX_LIMIT:
        raise InputError(f"since must be >= 0 and limit 1..{MAX_LIMIT}")
    lines = lines_after(db, name, since, limit)
    if format == "json":
        return lines
    return csv_response(name, lines)
