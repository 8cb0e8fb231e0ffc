"""The inbox (programs received from the machines) and the hybrid net share's page."""

from __future__ import annotations

from urllib.parse import quote

from fastapi import APIRouter, Request
from fastapi.responses import HTMLResponse, Response

from opendnc.errors import InputError
from opendnc.server import actions
from opendnc.server.actions.models import ReceivedState
from opendnc.server.web import render
from opendnc.server.web.pages.base import (
    ProgramField,
    ReceivedId,
    Viewing,
    Writing,
    html,
    is_htmx,
    redirect,
)

__all__ = ["router"]

router = APIRouter(include_in_schema=False)


@router.get("/inbox")
def inbox_page(request: Request, page: Viewing, state: str = "new") -> HTMLResponse:
    """Programs received from the machines."""
    try:
        states = [ReceivedState(state)] if state != "all" else list(ReceivedState)
    except ValueError:
        raise InputError(f"state {state[:20]!r}: new, accepted, discarded, failed or all") from None
    found = actions.inbox.list_received(page.svc, page.who, states)
    items = [r.model_dump(mode="json") for r in found]
    template = "_inbox.html" if is_htmx(request) else "inbox.html"
    return html(template, page, request, items=items, state=state)


@router.get("/inbox/{received_id}")
def received_page(request: Request, received_id: ReceivedId, page: Viewing) -> HTMLResponse:
    """One reception beside the library version of the same program."""
    svc, who = page.svc, page.who
    item = actions.inbox.get_received(svc, who, received_id)
    new = actions.inbox.received_content(svc, who, received_id).data
    old = actions.inbox.base_content(svc, who, received_id)
    return html(
        "received.html",
        page,
        request,
        item=item.model_dump(mode="json", exclude={"base", "diff"}),
        base=item.base.model_dump(mode="json") if item.base is not None else None,
        diff=render.side_by_side(render.program_text(old), render.program_text(new)),
        unified=item.diff,
    )


@router.post("/inbox/{received_id}/accept")
def accept_received(
    request: Request,
    received_id: ReceivedId,
    page: Writing,
    name: ProgramField = "",
) -> Response:
    """Make the reception a new draft version (programmers)."""
    version = actions.inbox.accept_received(page.svc, page.who, received_id, name.strip() or None)
    return redirect(request, f"/library/{quote(version.program)}?v={version.number}")


@router.post("/inbox/{received_id}/discard")
def discard_received(request: Request, received_id: ReceivedId, page: Writing) -> Response:
    """Drop the reception from the inbox (programmers)."""
    actions.inbox.discard_received(page.svc, page.who, received_id)
    return redirect(request, "/inbox")


@router.get("/netshare")
def netshare_page(request: Request, page: Viewing) -> HTMLResponse:
    """The hybrid net share: its folders and files beside the library, and what it did."""
    found = actions.netshare.net_share(page.svc, page.who)
    template = "_netshare.html" if is_htmx(request) else "netshare.html"
    return html(template, page, request, share=found.model_dump(mode="json"))
