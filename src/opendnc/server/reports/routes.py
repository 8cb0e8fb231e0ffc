"""``/reports/shift``: the shift report as a page and its CSV (for a logged-in person).

``day`` (the shop's date the shift began) and ``shift`` (its name) pick the shift; without
them, the last shift that ended."""

from __future__ import annotations

from datetime import UTC, date, datetime
from typing import Annotated
from urllib.parse import urlencode

from fastapi import APIRouter, Query, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import HTMLResponse, Response

from opendnc.errors import InputError
from opendnc.server.core.errors import NotFound
from opendnc.server.http import deps
from opendnc.server.reports.render import context_of
from opendnc.server.reports.shift import ShiftReport, build, last_finished, shift_period
from opendnc.server.web import render
from opendnc.server.web.pages.base import ROLES, Viewing

__all__ = ["router"]

router = APIRouter(include_in_schema=False)


def _report(request: Request, day: str, shift: str) -> ShiftReport:
    config = deps.machines(request).config
    now = datetime.now(UTC)
    if day or shift:
        try:
            when = date.fromisoformat(day)
        except ValueError:
            raise InputError("day: expected a date like 2026-03-29") from None
        period = shift_period(config, when, shift)
    else:
        found = last_finished(config, now)
        if found is None:
            raise NotFound("no shift has ended yet (or none is configured: [[shifts]])")
        period = found
    return build(deps.database(request).sessions, config, period, now)


Day = Annotated[str, Query(max_length=10)]
Shift = Annotated[str, Query(max_length=32)]


@router.get("/reports/shift")
async def shift_page(
    request: Request, page: Viewing, day: Day = "", shift: Shift = ""
) -> HTMLResponse:
    """The shift report."""

    def work() -> HTMLResponse:
        sr = _report(request, day, shift)
        query = urlencode({"day": sr.day.isoformat(), "shift": sr.period.shift})
        html = render.render(
            "shift_report.html",
            page=page,
            path=request.url.path,
            roles=ROLES,
            query=query,
            zone_label=render.zone_label(None, sr.report.calendar.zone),
            **context_of(sr),
        )
        return HTMLResponse(html)

    return await run_in_threadpool(work)


@router.get("/reports/shift.csv")
async def shift_csv(request: Request, page: Viewing, day: Day = "", shift: Shift = "") -> Response:
    """The shift report's figures as CSV."""
    _ = page

    def work() -> Response:
        sr = _report(request, day, shift)
        name = f"shift-{sr.day:%Y%m%d}-{sr.period.shift}.csv"
        return Response(
            sr.csv,
            media_type="text/csv; charset=utf-8",
            headers={"Content-Disposition": f'attachment; filename="{name}"'},
        )

    return await run_in_threadpool(work)
