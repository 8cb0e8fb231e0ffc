"""A machine's page: its card, status timeline, DPRNT console, queue and history, and what a
person does to its jobs there (cancel, move, retry, drip-feed)."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta
from typing import Annotated, Any

from fastapi import APIRouter, Form, Request
from fastapi.responses import HTMLResponse, Response

from opendnc.server import actions
from opendnc.server.actions.dprnt import MAX_LIMIT
from opendnc.server.actions.models import MAX_ID, JobKind, JobOut, JobRequest, JobState
from opendnc.server.kinds.capabilities import capabilities_of
from opendnc.server.web import render
from opendnc.server.web.pages.base import (
    JobId,
    NumberField,
    Page,
    ProgramField,
    Viewing,
    Writing,
    html,
)
from opendnc.server.web.pages.cards import cards
from opendnc.server.web.pages.live import CONSOLE_LINES

__all__ = ["TIMELINE_HOURS", "router"]

router = APIRouter(include_in_schema=False)
FINISHED = [JobState.DONE, JobState.FAILED, JobState.CANCELLED, JobState.INTERRUPTED]
TIMELINE_HOURS = 4


def _job_row(job: JobOut) -> dict[str, Any]:
    row = job.model_dump(mode="json")
    if job.program is None:  # a report names its program, a receive or delete its path
        row["program"] = str(job.params.get("name") or job.params.get("path") or "")
    return row


def _timeline(page: Page, name: str) -> dict[str, Any]:
    state = page.svc.machine(name)
    timeline = page.parts.timeline
    timeline.note(name, state.reading(), online=state.online)
    now = datetime.now(UTC)
    return {
        "timeline": timeline.segments(name, hours=TIMELINE_HOURS, now=now),
        "timeline_ticks": render.axis_ticks(
            now - timedelta(hours=TIMELINE_HOURS), now, page.parts.calendar.zone
        ),
        "timeline_hours": TIMELINE_HOURS,
        "timeline_days": timeline.retention.total_seconds() / 86400,
    }


def _dprnt(page: Page, name: str) -> dict[str, Any]:
    found = actions.dprnt.recent_lines(page.svc, page.who, name, CONSOLE_LINES)
    lines = [x.model_dump(mode="json") for x in found]
    return {
        "lines": lines,
        "span": f"{found[0].id}-{found[-1].id}" if found else "0-0",
        "status": page.parts.capture.status.get(name, ""),
    }


def _machine_context(page: Page, name: str) -> dict[str, Any]:
    svc, who = page.svc, page.who
    state = svc.machine(name)

    def rows(states: list[JobState], limit: int = 200) -> list[dict[str, Any]]:
        found = actions.queue.list_jobs(svc, who, machine=name, states=states, limit=limit)
        return [_job_row(j) for j in found]

    caps = capabilities_of(state.config)
    context: dict[str, Any] = {
        "queue": rows([JobState.QUEUED]),
        "running": rows([JobState.RUNNING]),
        "history": rows(FINISHED, 50),
        "machine": state.as_json(),
        **_timeline(page, name),
        "console_lines": CONSOLE_LINES,
        "dripfeed": caps.dripfeed,
        "released": actions.library.released_names(svc, who) if caps.dripfeed else [],
        "has_files": caps.file_browser,
        "dprnt": _dprnt(page, name) if caps.dprnt else None,
    }
    context["card"] = cards(page, [name])[0]
    return context


@router.get("/machines/{name}")
def machine_page(request: Request, name: str, page: Viewing) -> HTMLResponse:
    """The machine's status, queue and job history."""
    return html("machine.html", page, request, **_machine_context(page, name))


@router.get("/machines/{name}/dprnt.csv")
def machine_dprnt_csv(name: str, page: Viewing) -> Response:
    """The machine's newest DPRNT lines (up to the API's limit) as CSV, oldest first."""
    lines = actions.dprnt.recent_lines(page.svc, page.who, name, MAX_LIMIT)
    return Response(
        actions.dprnt.csv_text(name, lines),
        media_type="text/csv",
        headers={"Content-Disposition": f'attachment; filename="{name}-dprnt.csv"'},
    )


@router.get("/machines/{name}/jobs")
def machine_jobs(request: Request, name: str, page: Viewing) -> HTMLResponse:
    """The queue and history fragment (refreshed by the page while jobs run)."""
    return jobs_fragment(request, page, name)


def jobs_fragment(request: Request, page: Page, machine: str) -> HTMLResponse:
    """The machine's queue and history: what the page shows again after a job action."""
    return html("_jobs.html", page, request, **_machine_context(page, machine))


@router.post("/jobs/{job_id}/cancel")
def cancel_job(request: Request, job_id: JobId, page: Writing) -> HTMLResponse:
    """Cancel a queued job, or ask a running one to stop (at its next safe point)."""
    job = actions.queue.cancel_job(page.svc, page.who, job_id)
    return jobs_fragment(request, page, job.machine)


@router.post("/jobs/{job_id}/move")
def move_job(
    request: Request, job_id: JobId, page: Writing, index: Annotated[int, Form(ge=0, le=MAX_ID)]
) -> HTMLResponse:
    """Put a queued job at ``index`` in its queue."""
    job = actions.queue.move_job(page.svc, page.who, job_id, index)
    return jobs_fragment(request, page, job.machine)


@router.post("/jobs/{job_id}/retry")
def retry_job(
    request: Request, job_id: JobId, page: Writing, from_line: NumberField = None
) -> HTMLResponse:
    """Queue a failed, interrupted or cancelled job again (a drip-feed from a line, which
    programmers restart: it runs the machine)."""
    job = actions.queue.retry_job(page.svc, page.who, job_id, from_line)
    return jobs_fragment(request, page, job.machine)


@router.post("/machines/{name}/dripfeed")
def start_dripfeed(
    request: Request,
    name: str,
    page: Writing,
    program: ProgramField,
    from_line: NumberField = None,
) -> HTMLResponse:
    """Drip-feed the released version of ``program`` to the machine (programmers; the page
    asks first, since the machine runs it as it arrives)."""
    order = JobRequest(
        kind=JobKind.DRIPFEED, program=program.strip(), machines=[name], from_line=from_line
    )
    job = actions.queue.create_jobs(page.svc, page.who, order)[0]
    return jobs_fragment(request, page, job.machine)
