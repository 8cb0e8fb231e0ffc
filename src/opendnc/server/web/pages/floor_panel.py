"""The machine page's floor panel and the stop-reasons page for a tablet
(``/floor/reasons/<machine>``). The panel: today's OEE and parts against the goal, the stops of the
last two days that ask for a reason (longer than ``[downtime] threshold``) with a reason
picker each, and a form to report parts good and scrapped. Every write is an action
(:mod:`opendnc.server.actions.floor`); every figure is :func:`.answer.full_report`'s, the
one the utilization page and the API show."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta
from typing import Annotated, Any

from fastapi import APIRouter, Form, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import HTMLResponse

from opendnc.errors import InputError
from opendnc.server import actions
from opendnc.server.actions import floor
from opendnc.server.utilization.collect import Group, Report
from opendnc.server.web import render
from opendnc.server.web.pages.base import ROLES, Page, Viewing, Writing, html

__all__ = ["floor_context", "router"]

router = APIRouter(include_in_schema=False)

Count = Annotated[int, Form(ge=0, le=floor.MAX_PARTS)]
Note = Annotated[str, Form(max_length=floor.NOTE_MAX)]


def floor_context(page: Page, name: str, now: datetime | None = None) -> dict[str, Any]:
    """What the panel shows of machine ``name``: yesterday and today on the shop's clock."""
    svc = page.svc
    svc.machine(name)
    config = page.parts.machines.config
    cal = config.calendar
    now = now or datetime.now(UTC)
    today = cal.local(now).date()
    first = today - timedelta(days=1)
    r: Report = actions.utilization.days_report(svc, page.who, first, today, Group.DAY, [name], now)
    mf = r.floor.of(name)
    threshold = config.downtime.threshold
    stops = [s for s in mf.stops if s.seconds >= threshold]
    stops.sort(key=lambda s: s.stop.start, reverse=True)
    return {
        "machine": name,
        "today": mf.periods[-1],
        "stops": stops,
        "reasons": config.downtime.reasons,
        "threshold_min": round(threshold / 60),
        "clock": lambda at: cal.local(at).strftime("%a %H:%M"),
        "duration": lambda s: f"{int(s // 3600)}:{int(s % 3600 // 60):02d}",
        "percent": lambda v: "–" if v is None else f"{100 * v:.1f} %",
    }


def _panel(page: Page, name: str, note: str = "") -> HTMLResponse:
    context = floor_context(page, name)
    html = render.render("_floor.html", page=page, roles=ROLES, notice=note, **context)
    return HTMLResponse(html)


@router.get("/machines/{name}/floor")
async def floor_panel(request: Request, name: str, page: Viewing) -> HTMLResponse:
    """The floor panel (loaded by the machine page)."""
    return await run_in_threadpool(_panel, page, name)


@router.post("/machines/{name}/floor/reason")
async def pick_reason(
    request: Request,
    name: str,
    page: Writing,
    start: Annotated[str, Form(max_length=40)],
    reason: Annotated[str, Form(max_length=64)],
    note: Note = "",
) -> HTMLResponse:
    """Record the reason for one stop, then show the panel again."""
    try:
        began = datetime.fromisoformat(start)
    except ValueError:
        raise InputError(f"start: not a time: {start!r}") from None

    def work() -> HTMLResponse:
        done = floor.pick_reason(page.svc, page.who, name, began, reason, note)
        return _panel(page, name, f"Reason “{done.reason}” recorded.")

    return await run_in_threadpool(work)


@router.post("/machines/{name}/floor/parts")
async def report_parts(
    request: Request, name: str, page: Writing, good: Count = 0, scrap: Count = 0, note: Note = ""
) -> HTMLResponse:
    """Report parts good and scrapped, then show the panel again."""

    def work() -> HTMLResponse:
        done = floor.report_parts(page.svc, page.who, name, good, scrap, note)
        return _panel(page, name, f"{done.good} good, {done.scrap} scrapped recorded.")

    return await run_in_threadpool(work)


def _tablet(request: Request, page: Page, name: str, note: str = "") -> HTMLResponse:
    context = floor_context(page, name)
    return html("floor_reasons.html", page, request, notice=note, **context)


@router.get("/floor/reasons/{name}")
async def reasons_tablet(request: Request, name: str, page: Viewing) -> HTMLResponse:
    """A page for a tablet beside the machine: its stops that ask for a reason, newest
    first, each with a large button per reason (operators and up may press them)."""
    return await run_in_threadpool(_tablet, request, page, name)


@router.post("/floor/reasons/{name}")
async def reasons_tablet_pick(
    request: Request,
    name: str,
    page: Writing,
    start: Annotated[str, Form(max_length=40)],
    reason: Annotated[str, Form(max_length=64)],
) -> HTMLResponse:
    """Record the reason pressed for one stop (the action checks the role and audits it),
    then show the page again."""
    try:
        began = datetime.fromisoformat(start)
    except ValueError:
        raise InputError(f"start: not a time: {start!r}") from None

    def work() -> HTMLResponse:
        done = floor.pick_reason(page.svc, page.who, name, began, reason)
        when = page.parts.calendar.local(done.start).strftime("%H:%M")
        return _tablet(request, page, name, f"“{done.reason}” recorded for the stop from {when}.")

    return await run_in_threadpool(work)
