"""``GET /api/alerts``: whether each alert target is reachable, what waits for it, and the
open episodes (docs/server.md#alerts).

Kept beside :mod:`opendnc.server.http.api` (same key check) so the alerts add no line to the main
route table. The route is async: it reads the component's state on the event loop, the only
thread that changes it.
"""

from __future__ import annotations

from fastapi import APIRouter, Request
from pydantic import BaseModel

from opendnc.server.actions import require
from opendnc.server.actions.models import Role, Timestamp
from opendnc.server.alerts.component import Alerts
from opendnc.server.core.components import core_of
from opendnc.server.http.edge import ApiRoute
from opendnc.server.http.shared import ERRORS, Viewer

__all__ = ["AlertEpisodeOut", "AlertTargetOut", "AlertsOut", "router"]

router = APIRouter(prefix="/api", responses=ERRORS, route_class=ApiRoute)


class AlertTargetOut(BaseModel):
    """One target: its name in the rules, how the audit trail names it, how it goes."""

    name: str
    target: str
    reachable: bool  # false from a failed delivery until the next one that goes
    queued: int  # alerts waiting for it
    dropped: int  # alerts lost to a full queue since the server started


class AlertEpisodeOut(BaseModel):
    """A rule's condition that holds on a machine now (whether or not it alerted yet)."""

    rule: str
    machine: str
    since: Timestamp


class AlertsOut(BaseModel):
    """The alerts' state; ``configured`` false (and empty lists) without ``[alerts]``."""

    configured: bool
    targets: list[AlertTargetOut]
    open: list[AlertEpisodeOut]


@router.get("/alerts")
async def alerts_state(request: Request, who: Viewer) -> AlertsOut:
    """The alert targets (reachable, queued, dropped) and the open episodes."""
    require(who, Role.VIEWER)
    part = core_of(request.app).find(Alerts)
    if part is None:
        return AlertsOut(configured=False, targets=[], open=[])
    targets = [
        AlertTargetOut(
            name=t.name,
            target=t.describe(),
            reachable=not part.down[t.name],
            queued=len(part.outboxes[t.name].items),
            dropped=part.outboxes[t.name].dropped,
        )
        for t in part.config.targets
    ]
    episodes = [
        AlertEpisodeOut(rule=rule, machine=machine, since=since)
        for (rule, machine), since in sorted(part.engine.open_episodes().items())
    ]
    return AlertsOut(configured=True, targets=targets, open=episodes)
