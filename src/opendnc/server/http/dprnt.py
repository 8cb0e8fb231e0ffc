"""``/api/machines/{name}/dprnt``: the DPRNT lines the server captured, as JSON or CSV.

Kept beside :mod:`opendnc.server.http.api` (it uses the same key check and database session) so the
capture can be read without touching the main route table. ``since`` is the id of the last
line a client has seen: polling with it returns only newer lines, in order. The dashboard's
DPRNT console reads through :func:`recent_lines` and downloads through :func:`csv_response`.
"""

from __future__ import annotations

import csv
import io
from collections.abc import Sequence
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Query, Request
from fastapi.responses import Response
from pydantic import BaseModel
from sqlalchemy import select
from sqlalchemy.orm import Session

from opendnc.server.actions import require
from opendnc.server.actions.models import MAX_ID, Timestamp
from opendnc.server.core.errors import NotFound
from opendnc.server.http import deps
from opendnc.server.http.edge import ApiRoute
from opendnc.server.http.shared import ERRORS, Db, Viewer
from opendnc.server.machines.dprnt_capture import line_json
from opendnc.server.store.models import DprntLine, Role

__all__ = ["CSV_COLUMNS", "csv_response", "lines_after", "recent_lines", "router"]

CSV_COLUMNS = ["id", "at", "machine", "line", "fields", "complete"]
MAX_LIMIT = 10_000

router = APIRouter(prefix="/api", responses=ERRORS, route_class=ApiRoute)


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


class FieldOut(BaseModel):
    """One number of a DPRNT line, with the label printed before it (empty if none)."""

    label: str
    value: float


class DprntLineOut(BaseModel):
    """One line a machine printed, as the server captured it."""

    id: int
    machine: str
    at: Timestamp
    line: str
    numbers: list[float]
    fields: list[FieldOut]
    complete: bool


@router.get(
    "/machines/{name}/dprnt",
    response_model=list[DprntLineOut],
    responses={200: {"content": {"text/csv": {"schema": {"type": "string"}}}}},
)
def machine_dprnt(
    request: Request,
    name: str,
    db: Db,
    who: Viewer,
    since: Annotated[int, Query(ge=0, le=MAX_ID)] = 0,
    limit: Annotated[int, Query(ge=1, le=MAX_LIMIT)] = 1000,
    format: Literal["json", "csv"] = "json",
) -> list[dict[str, Any]] | Response:
    """Lines after id ``since``, oldest first (at most ``limit``); ``format=csv`` for a file."""
    require(who, Role.VIEWER)
    if name not in deps.machines(request).machines:
        raise NotFound(f"no machine named {name!r}")
    lines = lines_after(db, name, since, limit)
    if format == "json":
        return lines
    return csv_response(name, lines)
