"""DPRNT read actions: the lines a machine printed, as the server captured them.

The API (``GET /api/machines/{name}/dprnt``) and the machine page's console read the same
lines through these, with the same role check and the same answer for a machine that is not
configured.
"""

from __future__ import annotations

import csv
import io
from collections.abc import Sequence

from pydantic import BaseModel

from opendnc.server.actions.base import Caller, Services, require
from opendnc.server.actions.models import Timestamp
from opendnc.server.machines import dprnt_capture
from opendnc.server.store.models import Role

__all__ = [
    "CSV_COLUMNS",
    "MAX_LIMIT",
    "DprntLineOut",
    "FieldOut",
    "csv_text",
    "lines_after",
    "recent_lines",
]

CSV_COLUMNS = ["id", "at", "machine", "line", "fields", "complete"]
MAX_LIMIT = 10_000
"""The most lines one read returns (the API's ``limit``, the page's CSV)."""


class FieldOut(BaseModel):
    """One number of a DPRNT line, with the label printed before it (empty if none)."""

    label: str
    value: float


class DprntLineOut(BaseModel):
    """One line a machine printed, as the server captured it."""

    id: int
    machine: str
    at: Timestamp
    line: str
    numbers: list[float]
    fields: list[FieldOut]
    complete: bool


def lines_after(
    svc: Services, who: Caller, machine: str, since: int, limit: int
) -> list[DprntLineOut]:
    """``machine``'s lines after id ``since``, oldest first, at most ``limit`` (viewers;
    :class:`~opendnc.server.core.errors.NotFound` for a machine not configured)."""
    require(who, Role.VIEWER)
    svc.machine(machine)
    found = svc.read(lambda s: dprnt_capture.lines_after(s, machine, since, min(limit, MAX_LIMIT)))
    return [DprntLineOut.model_validate(x) for x in found]


def recent_lines(svc: Services, who: Caller, machine: str, limit: int) -> list[DprntLineOut]:
    """``machine``'s newest ``limit`` lines, oldest first (what a console shows; viewers)."""
    require(who, Role.VIEWER)
    svc.machine(machine)
    found = svc.read(lambda s: dprnt_capture.newest_lines(s, machine, min(limit, MAX_LIMIT)))
    return [DprntLineOut.model_validate(x) for x in found]


def csv_text(machine: str, lines: Sequence[DprntLineOut]) -> str:
    """``lines`` as CSV (RFC 4180: quoted where a value holds a comma, a quote or a line end;
    quotes doubled; CR LF between records)."""
    out = io.StringIO()
    writer = csv.writer(out)
    writer.writerow(CSV_COLUMNS)
    for line in lines:
        fields = " ".join(
            f"{f.label}={f.value:g}" if f.label else f"{f.value:g}" for f in line.fields
        )
        complete = "yes" if line.complete else "no"
        at = line.at.isoformat()  # the same text as the JSON answer
        writer.writerow([line.id, at, machine, line.line, fields, complete])
    return out.getvalue()
