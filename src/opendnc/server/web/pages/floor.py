"""The shop floor: the overview (a card per machine) and the wall display, each card with its
glance: the shift's parts against the goal and today so far (``/floor/glances`` refreshes
them; the figures are the utilization page's, :func:`.actions.utilization.floor_glance`)."""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Annotated, Any

from fastapi import APIRouter, Query, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import HTMLResponse

from opendnc.server import actions
from opendnc.server.actions.base import require
from opendnc.server.actions.models import Role
from opendnc.server.web import render
from opendnc.server.web.pages.base import Page, Viewing, html
from opendnc.server.web.pages.cards import cards
from opendnc.server.web.pages.utilization import hours_text, percent_text

__all__ = [
    "GLANCE_FRESH",
    "GLANCE_SECONDS",
    "WALL_SECONDS",
    "GlanceCache",
    "glance_context",
    "glance_words",
    "router",
]

router = APIRouter(include_in_schema=False)
WALL_SECONDS = 15  # each page of the wall display shows this long
GLANCE_SECONDS = 60  # the glances are read again this often (a part takes minutes)
# Glances this young are shown again to the next page that asks: every open overview and wall
# display reads them each minute, and 200 machines' take about 2 CPU seconds (measured).
GLANCE_FRESH = 30.0


@dataclass
class GlanceCache:
    """The glances last read, shared by the pages of one server (they show every viewer
    the same figures): read again once older than :data:`GLANCE_FRESH`, by one page at a
    time (the others wait for its answer instead of asking the database too)."""

    lock: threading.Lock = field(default_factory=threading.Lock)
    held: dict[tuple[str, ...], tuple[float, dict[str, Any]]] = field(default_factory=dict)

    def get(self, page: Page, names: list[str]) -> dict[str, Any]:
        """The glances of ``names``, read again if stale (a viewer's, as the action's)."""
        require(page.who, Role.VIEWER)  # the action's own check, for a caller served held ones
        key = tuple(names)
        with self.lock:
            found = self.held.get(key)
            if found is not None and time.monotonic() - found[0] < GLANCE_FRESH:
                return found[1]
            glances = actions.utilization.floor_glance(page.svc, page.who, names)
            self.held = {key: (time.monotonic(), glances)}  # one shop, one list of names
            return glances


def glance_words() -> dict[str, Any]:
    """How ``_glance.html`` writes its figures: as the utilization page writes them."""
    return {
        "pct": percent_text,
        "fraction": lambda v: percent_text(None if v is None else 100.0 * v),
        "duration": hours_text,
    }


def glance_context(
    page: Page, names: list[str], cache: GlanceCache | None = None
) -> dict[str, Any]:
    """What ``_glance.html`` needs for ``names``: each machine's glance (from ``cache`` if
    it holds fresh ones) and the words."""
    if cache is not None:
        found = cache.get(page, names)
    else:
        found = actions.utilization.floor_glance(page.svc, page.who, names, datetime.now(UTC))
    return {"glances": found, "glance_every": GLANCE_SECONDS, **glance_words()}


def _cache(request: Request) -> GlanceCache:
    # one per app (a test process serves several shops)
    state = request.app.state
    cache = getattr(state, "glances", None)
    if cache is None:
        cache = state.glances = GlanceCache()
    return cache


def _floor(page: Page, cache: GlanceCache) -> dict[str, Any]:
    # what the overview and the wall display show: the cards, how many are in each state,
    # the machines in alarm, and each card's glance
    found = cards(page)
    counts = {state: sum(1 for c in found if c.state == state) for state in render.STATES}
    in_alarm = [c for c in found if c.state == "alarm"]
    glance = glance_context(page, [c.name for c in found], cache)
    return {"cards": found, "counts": counts, "in_alarm": in_alarm, **glance}


@router.get("/")
async def overview(request: Request, page: Viewing) -> HTMLResponse:
    """A card per machine, kept live by server-sent events."""
    context = await run_in_threadpool(_floor, page, _cache(request))
    return html("overview.html", page, request, **context)


@router.get("/wall")
async def wall(
    request: Request,
    page: Viewing,
    every: Annotated[int, Query(ge=3, le=600)] = WALL_SECONDS,
) -> HTMLResponse:
    """The floor for a screen on the wall: large type, no controls, the pages of a shop
    larger than the screen shown in turn (``every`` seconds each)."""
    context = await run_in_threadpool(_floor, page, _cache(request))
    return html("wall.html", page, request, every=every, **context)


@router.get("/floor/glances")
async def glances(request: Request, page: Viewing) -> HTMLResponse:
    """Every card's glance again, each an out-of-band swap of ``#glance-<machine>``."""

    def work() -> str:
        names = list(page.parts.machines.machines)
        context = glance_context(page, names, _cache(request))
        return "".join(
            render.render("_glance.html", g=g, oob=True, **context)
            for g in context["glances"].values()
        )

    return HTMLResponse(await run_in_threadpool(work))
