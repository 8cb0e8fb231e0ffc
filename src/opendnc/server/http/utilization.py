"""``GET /api/utilization``: the route, a thin adapter over the read action
:func:`opendnc.server.actions.utilization.report_for` and
:func:`opendnc.server.utilization.answer.report_response` (docs/dashboard.md#utilization).

It shares only the documented errors and the caller's key check with the other API routes
(:mod:`opendnc.server.http.shared`), never the API's own module.
"""

from __future__ import annotations

from datetime import datetime
from typing import Annotated

from fastapi import APIRouter, FastAPI, Path, Query
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import Response
from pydantic import BaseModel, Field

from opendnc.errors import InputError
from opendnc.server import actions
from opendnc.server.actions import floor
from opendnc.server.actions.models import MAX_ID
from opendnc.server.http.edge import ApiRoute
from opendnc.server.http.shared import ERRORS, Svc, Viewer
from opendnc.server.utilization.answer import report_response

__all__ = ["install", "router"]

# The API's documented errors and its route class (sessions, strict JSON), as every /api route.
router = APIRouter(prefix="/api", responses=ERRORS, route_class=ApiRoute)


def install(app: FastAPI) -> None:
    """Add ``/api/utilization`` to ``app``."""
    app.include_router(router)


@router.get(
    "/utilization",
    response_class=Response,
    responses={
        200: {
            "content": {
                "application/json": {"schema": {"type": "object"}},
                "text/csv": {"schema": {"type": "string"}},
            }
        }
    },
)
async def utilization(
    svc: Svc,
    who: Viewer,
    start: Annotated[str | None, Query(alias="from")] = None,
    end: Annotated[str | None, Query(alias="to")] = None,
    machines: Annotated[list[str] | None, Query()] = None,
    group: str = "day",
    format: str = "json",
) -> Response:
    """Utilization per machine and period (JSON, or ``format=csv``)."""
    if format not in ("json", "csv"):
        raise InputError(f"format: expected json or csv, got {format!r}")

    def answer() -> Response:
        r = actions.utilization.report_for(
            svc, who, start=start, end=end, machines=machines, group=group
        )
        # the body too in the pool's thread: a year by week is 5 MB of JSON, and the event
        # loop serves every other request meanwhile
        return report_response(r, format)

    return await run_in_threadpool(answer)


class StandardIn(BaseModel):
    """A standard cycle time, in seconds."""

    seconds: float = Field(gt=0, le=floor.MAX_STANDARD)


class PartsIn(BaseModel):
    """Parts made: good and scrapped ones, and when (now by default)."""

    good: int = Field(0, ge=0, le=floor.MAX_PARTS)
    scrap: int = Field(0, ge=0, le=floor.MAX_PARTS)
    note: str = Field("", max_length=floor.NOTE_MAX)
    at: datetime | None = None


class ReasonIn(BaseModel):
    """The reason for the stop that began at ``start`` (as the utilization answer gives it)."""

    start: datetime
    reason: str = Field(max_length=64)
    note: str = Field("", max_length=floor.NOTE_MAX)


Name = Annotated[str, Path(max_length=255)]


@router.put("/programs/{name}/versions/{number}/standard")
def set_standard(
    svc: Svc,
    who: Viewer,
    name: Name,
    number: Annotated[int, Path(ge=1, le=MAX_ID)],
    body: StandardIn,
) -> floor.StandardOut:
    """Set the standard cycle time of a program version (approver and up; audited)."""
    return floor.set_standard(svc, who, name, number, body.seconds)


@router.post("/machines/{name}/parts", status_code=201)
def report_parts(svc: Svc, who: Viewer, name: Name, body: PartsIn) -> floor.PartsOut:
    """Report parts made on a machine, good and scrapped (operator and up; audited)."""
    return floor.report_parts(svc, who, name, body.good, body.scrap, body.note, body.at)


@router.post("/machines/{name}/downtime")
def pick_reason(svc: Svc, who: Viewer, name: Name, body: ReasonIn) -> floor.ReasonOut:
    """Record the reason for a stop of a machine (operator and up; audited)."""
    return floor.pick_reason(svc, who, name, body.start, body.reason, body.note)
