"""The answer of ``GET /api/utilization`` and of the utilization page's download: the
parameters parsed, the report computed, and written as JSON or CSV.

Parameters (docs/dashboard.md#utilization): ``from`` and ``to`` as ISO 8601 instants with
an offset, or as dates (the shop's midnight in ``[server] timezone``); by default the last 7
days up to the end of today. ``machines`` names machines (comma-separated or repeated; all
by default), ``group`` is ``shift``, ``day`` or ``week``, ``format=csv`` gives the table the
dashboard exports. Every time in the answer is on the shop's clock with its offset
(``2026-03-29T03:00:00+02:00``).
"""

from __future__ import annotations

import csv
import io
from datetime import UTC, date, datetime, time, timedelta
from typing import Any

from fastapi.responses import Response
from pydantic_core import to_json
from sqlalchemy.orm import Session, sessionmaker

from opendnc.errors import InputError
from opendnc.server.config.downtime import NO_REASON
from opendnc.server.config.shop import ShopConfig
from opendnc.server.core.errors import NotFound
from opendnc.server.core.gc_pause import paused
from opendnc.server.core.shifts import DAYS, Calendar, Period
from opendnc.server.store.db import read_only
from opendnc.server.utilization.collect import (
    STATES,
    Figures,
    Group,
    MachineReport,
    Report,
    Stretch,
    report,
    sum_safely,
)
from opendnc.server.utilization.oee import FloorReport, Oee, floor_of

__all__ = [
    "CSV_COLUMNS",
    "csv_text",
    "full_report",
    "parse_span",
    "report_json",
    "report_response",
    "run_report",
]

DEFAULT_DAYS = 7
CSV_COLUMNS = [
    "machine",
    "period",
    "shift",
    "start",
    "end",
    *(f"{s.value}_h" for s in STATES),
    "shift_h",
    "utilization_pct",
    "utilization_recorded_pct",
    "parts",
    "runs",
    "cycle_mean_s",
    "availability_pct",
    "performance_pct",
    "quality_pct",
    "oee_pct",
    "parts_made",
    "parts_good",
    "parts_scrap",
    "parts_goal",
    "stops_h",
]
DEFINITIONS = {
    "utilization": "running time within shifts / shift time (percent)",
    "utilization_recorded": "running time / recorded time, i.e. time less no record (percent)",
    "parts": "increases of the control's part counter; null where it reports none",
    "runs": "program runs that ended: the part counter rising, or running back to ready",
    "stops": "5 minutes or more not running, named by the worst state in them",
    "availability": "running time within shifts / planned (shift) time; the utilization",
    "performance": "standard cycle time x runs / the running time of those runs",
    "quality": "good parts / parts made (reported, else the control's counter, else runs)",
    "oee": "availability x performance x quality",
    "goal": "the parts set in [goals] for the period, else those its planned time makes "
    "at the standard pace",
    "expected": "the goal's part of the period up to now",
    "lost": "stop time per downtime reason, by the period the stop began in",
}


def parse_when(text: str, calendar: Calendar, key: str) -> datetime:
    """An ISO 8601 instant with an offset, or a date (the shop's midnight starting it)."""
    text = text.strip()
    try:
        if len(text) == 10:
            return calendar.instant(date.fromisoformat(text), time(0))
        value = datetime.fromisoformat(text.replace("Z", "+00:00"))
    except ValueError:
        raise InputError(
            f"{key}: expected an ISO 8601 time with offset or a date, got {text!r}"
        ) from None
    if value.tzinfo is None:
        raise InputError(f"{key}: {text!r} has no UTC offset (add +01:00 or Z, or give a date)")
    return value.astimezone(UTC)


def parse_span(
    calendar: Calendar, start: str | None, end: str | None, now: datetime | None = None
) -> tuple[datetime, datetime]:
    """``from`` and ``to``; by default the last 7 days up to the end of today (shop clock)."""
    now = now or datetime.now(UTC)
    if end:
        until = parse_when(end, calendar, "to")
    else:
        until = calendar.instant(calendar.local(now).date() + timedelta(days=1), time(0))
    if start:
        since = parse_when(start, calendar, "from")
    else:
        local_end = calendar.local(until).date()
        since = calendar.instant(local_end - timedelta(days=DEFAULT_DAYS), time(0))
    if until <= since:
        raise InputError("to: must be after from")
    return since, until


def pick_machines(config: ShopConfig, names: list[str] | None) -> list[str]:
    """The machines asked for (all configured ones by default); :class:`NotFound` for one
    that is not configured."""
    known = [m.name for m in config.machines]
    if not names:
        return known
    out: list[str] = []
    for item in names:
        for name in item.split(","):
            name = name.strip()
            if not name:
                continue
            if name not in known:
                raise NotFound(f"no machine named {name!r}")
            if name not in out:
                out.append(name)
    return out


def run_report(
    sessions: sessionmaker[Session],
    config: ShopConfig,
    *,
    start: str | None,
    end: str | None,
    machines: list[str] | None,
    group: str,
    now: datetime | None = None,
) -> Report:
    """Parse the parameters and compute the report (summing finished hours first)."""
    try:
        grouping = Group(group)
    except ValueError:
        raise InputError(f"group: expected shift, day or week, got {group!r}") from None
    calendar = config.calendar
    since, until = parse_span(calendar, start, end, now)
    names = pick_machines(config, machines)
    return full_report(sessions, config, names, since, until, grouping, now)


def full_report(
    sessions: sessionmaker[Session],
    config: ShopConfig,
    names: list[str],
    since: datetime,
    until: datetime,
    grouping: Group,
    now: datetime | None = None,
) -> Report:
    """The report every page, the API, the CSV and the shift report read: utilization, and
    with it OEE, parts and the stops with their reasons (:func:`.oee.floor_of`)."""
    now = now or datetime.now(UTC)
    calendar = config.calendar
    with sessions.begin() as session:  # short: what finished since the last summing
        sum_safely(session, names, now, calendar)
    # the question itself only reads (on SQLite it does not hold the write lock meanwhile)
    with read_only(sessions)() as session:
        r = report(session, calendar, names, since, until, grouping, now=now, sum_first=False)
        retention = timedelta(days=config.server.timeline_days)
        r.floor = floor_of(session, r, retention, config.downtime.reasons, now, config.goals)
    return r


def _local(at: datetime, calendar: Calendar) -> str:
    return at.astimezone(calendar.zone).isoformat()


def _pct(value: float | None) -> float | None:
    return None if value is None else round(value, 2)


# (a year per week is 10 000 figures: an enum member's ``.value`` is a slow property)
_NAMED = tuple((s, s.value) for s in STATES)


def figures_json(f: Figures) -> dict[str, Any]:
    """One machine's figures over some time as JSON (seconds, rounded to 0.1)."""
    seconds, scheduled = f.seconds, f.scheduled
    return {
        "seconds": {name: round(seconds[s], 1) for s, name in _NAMED},
        "shift_seconds": {name: round(scheduled[s], 1) for s, name in _NAMED},
        "utilization": _pct(f.utilization),
        "utilization_recorded": _pct(f.utilization_recorded),
        "parts": f.parts,
        "runs": f.runs,
        "cycle_mean_seconds": None if f.cycle_mean is None else round(f.cycle_mean, 1),
    }


def _fraction(value: float | None) -> float | None:
    return None if value is None else round(100.0 * value, 2)


def oee_json(o: Oee) -> dict[str, Any]:
    """One machine's OEE over some time as JSON (percentages, seconds rounded to 0.1)."""
    return {
        "availability": _fraction(o.availability),
        "performance": _fraction(o.performance),
        "quality": _fraction(o.quality),
        "oee": _fraction(o.oee),
        "planned_seconds": round(o.planned, 1),
        "ideal_seconds": round(o.ideal, 1),
        "timed_seconds": round(o.timed, 1),
        "parts_made": o.made,
        "parts_good": o.good,
        "parts_scrap": o.scrap,
        "parts_goal": o.goal,
        "parts_expected": o.expected,
        "missing_standards": list(o.missing),
    }


def floor_json(r: Report) -> dict[str, Any]:
    """The report's OEE and downtime as JSON: the Pareto, the standards in use, and per
    machine its stops with reasons (an empty dict where the report has none)."""
    floor: FloorReport | None = r.floor
    if floor is None:
        return {}
    cal = r.calendar
    return {
        "performance_from": _local(floor.covered_from, cal),
        "reasons": list(floor.reasons),
        "pareto": [
            {
                "reason": p.reason,
                "stops": p.stops,
                "seconds": round(p.seconds, 1),
                "share": round(p.share, 2),
                "cumulative": round(p.cumulative, 2),
            }
            for p in floor.pareto
        ],
        "standards": [
            {
                "program": s.program,
                "version_id": s.version_id,
                "version": s.version,
                "seconds": s.seconds,
                "source": s.source or None,
            }
            for _key, s in sorted(floor.standards.items())
        ],
    }


def _machine_floor_json(r: Report, machine: str) -> dict[str, Any]:
    floor: FloorReport | None = r.floor
    m = floor.of(machine) if floor is not None else None
    if m is None:
        return {}
    cal = r.calendar
    return {
        "oee": oee_json(m.totals),
        "downtime": [
            {**_stretch_json(s.stop, cal), "reason": s.reason or None, "note": s.note}
            for s in m.stops
        ],
        "lost_seconds": {k: round(v, 1) for k, v in floor.lost_by_reason(machine).items()}
        if floor is not None
        else {},
    }


def _periods_json(r: Report, m: MachineReport) -> list[dict[str, Any]]:
    """One machine's figures per period (with its OEE where the report has it)."""
    floor: FloorReport | None = r.floor
    mf = floor.of(m.machine) if floor is not None else None
    if mf is None:
        return [
            {"key": p.key, **figures_json(f)} for p, f in zip(r.periods, m.periods, strict=True)
        ]
    return [
        {"key": p.key, **figures_json(f), "oee": oee_json(o)}
        for p, f, o in zip(r.periods, m.periods, mf.periods, strict=True)
    ]


def _stretch_json(s: Stretch, calendar: Calendar) -> dict[str, Any]:
    return {
        "start": _local(s.start, calendar),
        "end": _local(s.end, calendar),
        "seconds": round(s.seconds, 1),
        "state": s.state.value,
        "text": s.text,
        "ongoing": s.ongoing,
    }


def shifts_json(calendar: Calendar) -> list[dict[str, Any]]:
    """The configured shifts as JSON."""
    return [
        {
            "name": s.name,
            "days": [DAYS[d] for d in sorted(s.days)],
            "start": s.start.strftime("%H:%M"),
            "end": "24:00" if s.ends_at_midnight else s.end.strftime("%H:%M"),
        }
        for s in calendar.shifts
    ]


def report_json(r: Report) -> dict[str, Any]:
    """The whole report as JSON, times on the shop's clock with their offset."""
    cal = r.calendar
    return {
        "from": _local(r.start, cal),
        "to": _local(r.end, cal),
        # the figures end here: at "to", or at now when the span holds it
        "until": _local(r.until or r.end, cal),
        "timezone": cal.zone_name,
        "group": r.group.value,
        "states": [s.value for s in STATES],
        "definitions": DEFINITIONS,
        "shifts": shifts_json(cal),
        "periods": [
            {
                "key": p.key,
                "start": _local(p.start, cal),
                "end": _local(p.end, cal),
                "shift": p.shift or None,
            }
            for p in r.periods
        ],
        "machines": [
            {
                "machine": m.machine,
                "totals": figures_json(m.totals),
                "periods": _periods_json(r, m),
                **_machine_floor_json(r, m.machine),
                "stops": [_stretch_json(s, cal) for s in m.stops],
                "alarms": [
                    {
                        "text": a.text,
                        "count": a.count,
                        "seconds": round(a.seconds, 1),
                        "longest_seconds": round(a.longest, 1),
                    }
                    for a in m.alarms
                ],
                "recent_alarms": [_stretch_json(s, cal) for s in m.recent_alarms],
            }
            for m in r.machines
        ],
        **floor_json(r),
    }


def _hours(seconds: float) -> str:
    return f"{seconds / 3600:.3f}"


def _opt(value: float | int | None, digits: int = 1) -> str:
    if value is None:
        return ""
    return str(value) if isinstance(value, int) else f"{value:.{digits}f}"


def _oee_cells(o: Oee | None) -> list[str]:
    if o is None:
        return [""] * 8
    return [
        _opt(_fraction(o.availability), 2),
        _opt(_fraction(o.performance), 2),
        _opt(_fraction(o.quality), 2),
        _opt(_fraction(o.oee), 2),
        _opt(o.made),
        _opt(o.good),
        str(o.scrap),
        _opt(o.goal),
    ]


def csv_text(r: Report) -> str:
    """The report as CSV: one row per machine and period, then the machine's total (period
    ``total``); hours with three decimals, times on the shop's clock with offset."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\r\n")
    floor: FloorReport | None = r.floor
    reasons = [*floor.reasons, NO_REASON] if floor is not None else []
    writer.writerow([*CSV_COLUMNS, *(f"lost_h:{name}" for name in reasons)])
    cal = r.calendar
    for m in r.machines:
        mf = floor.of(m.machine) if floor is not None else None
        rows: list[tuple[str, str, datetime, datetime, Figures, Oee | None, Period | None]]
        rows = [
            (p.key, p.shift, p.start, p.end, f, mf.periods[i] if mf else None, p)
            for i, (p, f) in enumerate(zip(r.periods, m.periods, strict=True))
        ]
        rows.append(("total", "", r.start, r.end, m.totals, mf.totals if mf else None, None))
        for key, shift, start, end, f, o, period in rows:
            lost = floor.lost_by_reason(m.machine, period) if floor is not None else {}
            writer.writerow(
                [
                    m.machine,
                    key,
                    shift,
                    _local(start, cal),
                    _local(end, cal),
                    *(_hours(f.seconds[s]) for s in STATES),
                    _hours(f.scheduled_total),
                    _opt(f.utilization, 2),
                    _opt(f.utilization_recorded, 2),
                    _opt(f.parts),
                    f.runs,
                    _opt(f.cycle_mean),
                    *_oee_cells(o),
                    _hours(sum(lost.values())) if floor is not None else "",
                    *(_hours(lost.get(name, 0.0)) for name in reasons),
                ]
            )
    return out.getvalue()


def csv_response(r: Report) -> Response:
    """The CSV as a download named after the span."""
    name = f"utilization-{r.calendar.local(r.start):%Y%m%d}-{r.calendar.local(r.end):%Y%m%d}.csv"
    return Response(
        csv_text(r),
        media_type="text/csv; charset=utf-8",
        headers={"Content-Disposition": f'attachment; filename="{name}"'},
    )


def report_response(r: Report, format: str = "json") -> Response:
    """The report as the API's answer: JSON, or the CSV download (``format="csv"``)."""
    with paused():  # (a JSON object per machine and period, all alive until sent)
        if format == "csv":
            return csv_response(r)
        # pydantic's encoder (FastAPI's own) writes the bytes the standard library's writes
        # for these plain values (JSONResponse: compact, UTF-8), three times as fast: a year
        # by week is 5 MB
        return Response(to_json(report_json(r)), media_type="application/json")
