"""The shift report as HTML: the page's and the e-mail's words and numbers, one renderer."""

from __future__ import annotations

from datetime import datetime
from typing import Any

from opendnc.server.reports.shift import ShiftReport
from opendnc.server.web import render
from opendnc.server.web.pages.utilization import hours_text, percent_text

__all__ = ["context_of", "mail_html", "subject_of"]


def subject_of(sr: ShiftReport, server: str = "") -> str:
    """The report's one-line title (the e-mail's subject)."""
    where = f" on {server}" if server else ""
    return f"Shift report{where}: {sr.period.shift} of {sr.day:%a %d %b %Y}"


def context_of(sr: ShiftReport) -> dict[str, Any]:
    """What the templates need to write ``sr``."""
    cal = sr.report.calendar

    def clock(at: datetime) -> str:
        return cal.local(at).strftime("%Y-%m-%d %H:%M %Z")

    return {
        "sr": sr,
        "percent": percent_text,
        "fraction": lambda v: percent_text(None if v is None else 100.0 * v),
        "duration": hours_text,
        "clock": clock,
        "zone_name": cal.zone_name,
        "shifts": cal.shifts,
    }


def mail_html(sr: ShiftReport, server: str = "", url: str = "") -> str:
    """The report as a self-contained HTML e-mail body."""
    return render.render(
        "shift_mail.html", subject=subject_of(sr, server), url=url, **context_of(sr)
    )
