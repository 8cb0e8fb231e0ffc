"""``/api/machines/{name}/dprnt``: the DPRNT lines the server captured, as JSON or CSV.

A thin adapter over :mod:`opendnc.server.actions.dprnt` (which the machine page's console reads
too), beside :mod:`opendnc.server.http.api` so the capture can be read without touching the
main route table. ``since`` is the id of the last line a client has seen: polling with it
returns only newer lines, in order.
"""

from __future__ import annotations

from typing import Annotated, Literal

from fastapi import APIRouter, Query
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import Response

from opendnc.server import actions
from opendnc.server.actions.dprnt import MAX_LIMIT, DprntLineOut
from opendnc.server.actions.models import MAX_ID
from opendnc.server.http.edge import ApiRoute
from opendnc.server.http.shared import ERRORS, Svc, Viewer

__all__ = ["csv_response", "router"]

router = APIRouter(prefix="/api", responses=ERRORS, route_class=ApiRoute)


def csv_response(machine: str, lines: list[DprntLineOut]) -> Response:
    """``lines`` as a CSV download (:func:`opendnc.server.actions.dprnt.csv_text`)."""
    return Response(
        actions.dprnt.csv_text(machine, lines),
        media_type="text/csv",
        headers={"Content-Disposition": f'attachment; filename="{machine}-dprnt.csv"'},
    )


@router.get(
    "/machines/{name}/dprnt",
    response_model=list[DprntLineOut],
    responses={200: {"content": {"text/csv": {"schema": {"type": "string"}}}}},
)
async def machine_dprnt(
    name: str,
    svc: Svc,
    who: Viewer,
    since: Annotated[int, Query(ge=0, le=MAX_ID)] = 0,
    limit: Annotated[int, Query(ge=1, le=MAX_LIMIT)] = 1000,
    format: Literal["json", "csv"] = "json",
) -> list[DprntLineOut] | Response:
    """Lines after id ``since``, oldest first (at most ``limit``); ``format=csv`` for a file."""
    lines = await run_in_threadpool(actions.dprnt.lines_after, svc, who, name, since, limit)
    if format == "json":
        return lines
    return csv_response(name, lines)
