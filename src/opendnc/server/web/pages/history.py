"""The history: the audit trail, filterable, newest first, and its CSV."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated
from urllib.parse import quote

from fastapi import APIRouter, Depends, Query, Request
from fastapi.responses import HTMLResponse, Response

from opendnc.server import actions
from opendnc.server.actions.models import MAX_ID, AuditOut
from opendnc.server.web.pages.base import Page, Short, Viewing, html

__all__ = ["router"]

router = APIRouter(include_in_schema=False)


@dataclass(frozen=True)
class _AuditFilters:
    """The history's filters as the person typed them (the form shows them again)."""

    machine: str
    action: str
    actor: str
    program: str

    def as_dict(self) -> dict[str, str]:
        return {
            "machine": self.machine,
            "action": self.action,
            "actor": self.actor,
            "program": self.program,
        }

    def rows(self, page: Page, limit: int, before: int | None = None) -> list[AuditOut]:
        """The audit rows they select, newest first (a blank filter selects everything)."""
        blank = {k: v.strip() or None for k, v in self.as_dict().items()}
        return actions.admin.list_audit(
            page.svc,
            page.who,
            machine=blank["machine"],
            action=blank["action"],
            actor=blank["actor"],
            program=blank["program"],
            limit=limit,
            before=before,
        )


def _audit_filters(
    machine: Short = "",
    action: Short = "",
    actor: Short = "",
    program: Annotated[str, Query(max_length=255)] = "",
) -> _AuditFilters:
    return _AuditFilters(machine, action, actor, program)


AuditFilters = Annotated[_AuditFilters, Depends(_audit_filters)]


@router.get("/history")
def history_page(
    request: Request,
    page: Viewing,
    filters: AuditFilters,
    before: Annotated[int | None, Query(ge=1, le=MAX_ID)] = None,
) -> HTMLResponse:
    """The audit trail, filterable, newest first."""
    rows = [r.model_dump(mode="json") for r in filters.rows(page, 100, before)]
    typed = filters.as_dict()
    query = "&".join(f"{k}={quote(v)}" for k, v in typed.items() if v.strip())
    machines = sorted(page.parts.machines.machines)
    return html(
        "history.html", page, request, rows=rows, filters=typed, query=query, machines=machines
    )


@router.get("/history.csv")
def history_csv(page: Viewing, filters: AuditFilters) -> Response:
    """The filtered audit trail as CSV (the API's export, for a logged-in person)."""
    return actions.admin.audit_csv_response(filters.rows(page, 10_000))
