"""``/standards``: the standard cycle time of every program, as OEE's performance counts it,
for a supervisor (approvers and up) to read and set. A program's time starts as the check's
estimate; one set here replaces it (audited ``standard.set``, docs/dashboard.md#oee)."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Form, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import HTMLResponse

from opendnc.server.actions import floor
from opendnc.server.actions.models import MAX_ID
from opendnc.server.web.pages.base import Page, Viewing, Writing, html

__all__ = ["router", "seconds_text"]

router = APIRouter(include_in_schema=False)


def seconds_text(seconds: float | None) -> str:
    """A cycle time as people read it: ``1:05.0`` (m:ss.s), ``1:02:03`` past an hour."""
    if seconds is None:
        return "–"
    if seconds >= 3600:
        whole = round(seconds)
        return f"{whole // 3600}:{whole % 3600 // 60:02d}:{whole % 60:02d}"
    minutes, rest = divmod(round(seconds, 1), 60)
    return f"{int(minutes)}:{rest:04.1f}"


def _page(request: Request, page: Page, note: str = "") -> HTMLResponse:
    rows = floor.standards(page.svc, page.who)
    clock = page.parts.calendar.local
    return html(
        "standards.html", page, request, rows=rows, notice=note, time=seconds_text,
        when=lambda at: clock(at).strftime("%Y-%m-%d %H:%M %Z") if at is not None else "",
        most=floor.MAX_STANDARD,
    )  # fmt: skip


@router.get("/standards")
async def standards_page(request: Request, page: Viewing) -> HTMLResponse:
    """Every program's standard cycle time (approvers and up)."""
    return await run_in_threadpool(_page, request, page)


@router.post("/standards")
async def set_standard(
    request: Request,
    page: Writing,
    program: Annotated[str, Form(max_length=100)],
    version: Annotated[int, Form(ge=1, le=MAX_ID)],
    seconds: Annotated[float, Form(gt=0, le=floor.MAX_STANDARD)],
) -> HTMLResponse:
    """Set one program version's standard time (the action checks the role and audits it),
    then show the page again."""

    def work() -> HTMLResponse:
        done = floor.set_standard(page.svc, page.who, program, version, seconds)
        note = f"{done.program} v{done.version}: standard {seconds_text(done.seconds)} set."
        return _page(request, page, note)

    return await run_in_threadpool(work)
