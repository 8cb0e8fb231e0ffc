"""The shop floor: the overview (a card per machine) and the wall display."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Query, Request
from fastapi.responses import HTMLResponse

from opendnc.server.web import render
from opendnc.server.web.pages.base import Page, Viewing, html
from opendnc.server.web.pages.cards import cards

__all__ = ["WALL_SECONDS", "router"]

router = APIRouter(include_in_schema=False)
WALL_SECONDS = 15  # each page of the wall display shows this long


def _floor(page: Page) -> dict[str, Any]:
    # what the overview and the wall display show: the cards, how many are in each state,
    # the machines in alarm
    found = cards(page)
    counts = {state: sum(1 for c in found if c.state == state) for state in render.STATES}
    in_alarm = [c for c in found if c.state == "alarm"]
    return {"cards": found, "counts": counts, "in_alarm": in_alarm}


@router.get("/")
def overview(request: Request, page: Viewing) -> HTMLResponse:
    """A card per machine, kept live by server-sent events."""
    return html("overview.html", page, request, **_floor(page))


@router.get("/wall")
def wall(
    request: Request,
    page: Viewing,
    every: Annotated[int, Query(ge=3, le=600)] = WALL_SECONDS,
) -> HTMLResponse:
    """The floor for a screen on the wall: large type, no controls, the pages of a shop
    larger than the screen shown in turn (``every`` seconds each)."""
    return html("wall.html", page, request, every=every, **_floor(page))
