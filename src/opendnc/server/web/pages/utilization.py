"""The utilization pages: a shop Gantt of states, stacked bars per machine and period, and the
table (exported as CSV), all server-rendered SVG and HTML over :mod:`opendnc.server.utilization`.

Every time a person reads is on the shop's clock with the zone's abbreviation
(``2026-03-29 03:00 CEST``); the page names the zone. The form takes whole days: ``from`` is
the first day shown and ``to`` the last (both included), in the shop's zone.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import UTC, date, datetime, time, timedelta
from decimal import ROUND_HALF_UP, Decimal
from typing import Annotated, Any
from urllib.parse import urlencode

from fastapi import APIRouter, Depends, Query, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import HTMLResponse, Response

from opendnc.errors import InputError
from opendnc.server import actions
from opendnc.server.config.shop import ShopConfig
from opendnc.server.core.shifts import Calendar, Period
from opendnc.server.core.state import State
from opendnc.server.utilization.answer import pick_machines, report_response
from opendnc.server.utilization.collect import STATES, Figures, Group, Report
from opendnc.server.web import render
from opendnc.server.web.pages.base import ROLES, Viewing, parts

__all__ = ["Bar", "GanttRow", "Segment", "router", "step_for"]

router = APIRouter(include_in_schema=False)
MAX_DAYS = 92  # a page draws at most a quarter (the API answers up to 400 days)
GANTT_BUCKETS = 400  # at most this many slices across the Gantt: more than its pixels
STEPS = [timedelta(minutes=m) for m in (5, 10, 15, 30, 60, 120, 180, 240, 360, 720, 1440)]
LABEL = {
    State.RUNNING: "running",
    State.READY: "ready",
    State.STOPPED: "stopped",
    State.ALARM: "alarm",
    State.OFFLINE: "offline",
    State.UNKNOWN: "unknown",
    State.NO_RECORD: "no record",
}


@dataclass(frozen=True)
class Segment:
    """A stretch of one state on a Gantt row, in percent of the row's width."""

    x: float
    width: float
    state: str
    title: str


@dataclass(frozen=True)
class GanttRow:
    """One machine's row of the shop Gantt."""

    machine: str
    segments: list[Segment]
    label: str  # the row's accessible name


@dataclass(frozen=True)
class Bar:
    """One period's stacked bar: (state, y, height) in percent, and what it reads."""

    key: str
    label: str
    stack: list[tuple[str, float, float]]
    utilization: str
    title: str
    x: float  # percent of the chart's width
    width: float
    short: str  # the utilization under a narrow bar (whole percent)


def step_for(start: datetime, end: datetime) -> timedelta:
    """The Gantt's slice: the shortest of :data:`STEPS` that keeps it within its buckets."""
    span = end - start
    for step in STEPS:
        if span / step <= GANTT_BUCKETS:
            return step
    return STEPS[-1]


def _clock(at: datetime, calendar: Calendar, *, day: bool = True) -> str:
    local = calendar.local(at)
    return local.strftime("%Y-%m-%d %H:%M %Z" if day else "%H:%M %Z")


def hours_text(seconds: float) -> str:
    minutes = round(seconds / 60)
    return f"{minutes // 60}:{minutes % 60:02d}"


def percent_text(value: float | None, decimals: int = 1) -> str:
    if value is None:
        return "–"
    # half up, as people round (56.25 reads 56.3), not to the nearest even binary float
    step = Decimal(1).scaleb(-decimals)
    return f"{Decimal(repr(value)).quantize(step, ROUND_HALF_UP)} %"


def _dominant(f: Figures) -> State:
    return max(STATES, key=lambda s: f.seconds[s])


def gantt_rows(
    calendar: Calendar,
    machines: list[str],
    periods: list[Period],
    figures: dict[str, list[Figures]],
    extent: tuple[datetime, datetime] | None = None,
) -> list[GanttRow]:
    """Each machine's slices merged into segments of its dominant state, placed on the
    row's ``extent`` (the slices' own by default). The slices of today end at now while the
    row is the whole day: drawn on their own span they would stretch over the future."""
    if not periods:
        return []
    start, end = extent if extent is not None else (periods[0].start, periods[-1].end)
    span = (end - start).total_seconds()
    rows = []
    for machine in machines:
        segments: list[Segment] = []
        runs: list[tuple[State, datetime, datetime]] = []
        for p, f in zip(periods, figures[machine], strict=True):
            state = _dominant(f)
            if runs and runs[-1][0] is state:
                runs[-1] = (state, runs[-1][1], p.end)
            else:
                runs.append((state, p.start, p.end))
        for state, a, b in runs:
            x = (a - start).total_seconds() / span * 100
            w = (b - a).total_seconds() / span * 100
            title = f"{LABEL[state]} {_clock(a, calendar)} to {_clock(b, calendar)}"
            segments.append(Segment(round(x, 3), round(w, 3), state.value, title))
        label = f"{machine}: " + "; ".join(
            f"{LABEL[s]} from {_clock(a, calendar)}" for s, a, _b in runs[:40]
        )
        rows.append(GanttRow(machine, segments, label))
    return rows


def axis_ticks(calendar: Calendar, start: datetime, end: datetime) -> list[tuple[float, str]]:
    """Labels under the Gantt at the shop's midnights (or every few hours within a day)."""
    span = (end - start).total_seconds()
    days = calendar.day_periods(start, end)
    ticks: list[tuple[float, str]] = []
    if len(days) <= 2:
        at = start.replace(minute=0, second=0, microsecond=0)
        while at < end:
            local = calendar.local(at)
            if at >= start and local.minute == 0 and local.hour % 3 == 0:
                x = (at - start).total_seconds() / span * 100
                ticks.append((x, _clock(at, calendar, day=False)))
            at += timedelta(hours=1)
        return ticks
    every = 1 if len(days) <= 10 else 7
    for i, d in enumerate(days):
        if d.start < start or i % every:
            continue
        label = calendar.local(d.start).strftime("%a %d %b")
        ticks.append(((d.start - start).total_seconds() / span * 100, label))
    return ticks


def bars(r: Report, figures: list[Figures]) -> list[Bar]:
    """One stacked bar per period of one machine (each bar is its period's whole time)."""
    out = []
    cal = r.calendar
    slot = 100 / max(len(r.periods), 1)
    for i, (p, f) in enumerate(zip(r.periods, figures, strict=True)):
        total = f.total or 1.0
        stack = []
        y = 100.0
        for s in STATES:
            h = f.seconds[s] / total * 100
            if h <= 0:
                continue
            y -= h
            stack.append((s.value, round(y, 3), round(h, 3)))
        local = cal.local(p.start)
        if r.group is Group.WEEK:
            label = p.key.split("-")[1]
        elif r.group is Group.SHIFT:
            label = f"{local:%a %d} {p.shift}"
        else:
            label = f"{local:%a %d}"
        parts = ", ".join(
            f"{LABEL[s]} {f.seconds[s] / total * 100:.1f} %" for s in STATES if f.seconds[s] > 0
        )
        title = f"{p.key}: utilization {percent_text(f.utilization)}; {parts}"
        x, width = round(i * slot + slot * 0.12, 3), round(slot * 0.76, 3)
        short = percent_text(f.utilization, 0 if len(r.periods) > 5 else 1)
        out.append(Bar(p.key, label, stack, percent_text(f.utilization), title, x, width, short))
    return out


def _span(calendar: Calendar, first: str, last: str, now: datetime) -> tuple[date, date]:
    today = calendar.local(now).date()
    try:
        day_to = date.fromisoformat(last) if last else today
        day_from = date.fromisoformat(first) if first else day_to - timedelta(days=6)
    except ValueError:
        raise InputError("from and to: expected dates like 2026-03-29") from None
    if day_to < day_from:
        raise InputError("to: the last day is before the first")
    if (day_to - day_from).days + 1 > MAX_DAYS:
        raise InputError(f"a page shows at most {MAX_DAYS} days (the API more)")
    return day_from, day_to


def _params(first: date, last: date, group: Group, machines: list[str] | None) -> str:
    query: list[tuple[str, str]] = [
        ("from", first.isoformat()),
        ("to", last.isoformat()),
        ("group", group.value),
    ]
    query += [("machines", m) for m in machines or []]
    return urlencode(query)


@dataclass(frozen=True)
class Question:
    """What the page and its CSV were asked: the span in whole local days, the grouping and
    the machines, read once from the query."""

    config: ShopConfig
    now: datetime
    first: date
    last: date
    grouping: Group
    names: list[str]
    machines: list[str] | None


def _question(
    request: Request,
    start: Annotated[str, Query(alias="from")] = "",
    end: Annotated[str, Query(alias="to")] = "",
    group: str = "day",
    machines: Annotated[list[str] | None, Query()] = None,
) -> Question:
    config = parts(request).machines.config
    now = datetime.now(UTC)
    first, last = _span(config.calendar, start, end, now)
    names = pick_machines(config, machines)
    return Question(config, now, first, last, _group(group), names, machines)


Asked = Annotated[Question, Depends(_question)]


@router.get("/utilization")
async def utilization_page(request: Request, page: Viewing, ask: Asked) -> HTMLResponse:
    """Utilization of the shop over whole days: Gantt, bars per period, the table."""
    cal, now, grouping = ask.config.calendar, ask.now, ask.grouping
    first, last, names, machines = ask.first, ask.last, ask.names, ask.machines
    found = await run_in_threadpool(
        actions.utilization.shop_figures,
        page.svc,
        page.who,
        first,
        last,
        grouping,
        names,
        step_for(cal.instant(first, time(0)), cal.instant(last + timedelta(days=1), time(0))),
        now,
    )
    r, slices, figures = found.report, found.slices, found.figures
    span_end = r.end
    shown = slices[-1].end if slices else r.start
    rows = gantt_rows(cal, names, slices, figures, (r.start, span_end))
    context: dict[str, Any] = {
        "report": r,
        "zone": cal.zone_name,
        "zone_name": cal.zone_name,  # the page's clock (base.html) and its label, as elsewhere
        "zone_label": render.zone_label(None, cal.zone),
        "first": first.isoformat(),
        "last": last.isoformat(),
        "group": grouping.value,
        "query": _params(first, last, grouping, machines),
        "rows": rows,
        "shown_pct": round((shown - r.start) / (span_end - r.start) * 100, 3),
        "ticks": axis_ticks(cal, r.start, span_end),
        "bars": {m.machine: bars(r, m.periods) for m in r.machines},
        "states": [(s.value, LABEL[s]) for s in STATES],
        "percent": percent_text,
        "duration": hours_text,
        "clock": lambda at: _clock(at, cal),
        "shifts": cal.shifts,
        "span_label": f"{_clock(r.start, cal)} to {_clock(span_end, cal)}"
        + (f" (counted up to now, {_clock(r.until, cal)})" if r.until and r.until < r.end else ""),
        "stops": sorted(
            ((m.machine, s) for m in r.machines for s in m.stops),
            key=lambda item: -item[1].seconds,
        )[:15],
        "alarms": [(m.machine, a) for m in r.machines for a in m.alarms],
        "floor": r.floor,
        "reason_of": _reason_of(r),
        "fraction": lambda v: percent_text(None if v is None else 100.0 * v),
    }
    html = render.render(
        "utilization.html", page=page, path=request.url.path, roles=ROLES, **context
    )
    return HTMLResponse(html)


def _reason_of(r: Report) -> Any:
    """The reason picked for a stop, by machine and the stop's start ("" while none is)."""
    picked = {
        (m.machine, s.stop.start): s.reason
        for m in (r.floor.machines if r.floor else [])
        for s in m.stops
    }
    return lambda machine, stop: picked.get((machine, stop.start), "")


def _group(value: str) -> Group:
    try:
        return Group(value)
    except ValueError:
        raise InputError(f"group: expected shift, day or week, got {value!r}") from None


@router.get("/utilization.csv")
async def utilization_csv(page: Viewing, ask: Asked) -> Response:
    """The page's table as CSV (the API's export, for a logged-in person)."""
    now, grouping = ask.now, ask.grouping
    first, last, names = ask.first, ask.last, ask.names

    def work() -> Response:
        r = actions.utilization.days_report(page.svc, page.who, first, last, grouping, names, now)
        return report_response(r, "csv")  # (in the pool's thread, not the event loop)

    return await run_in_threadpool(work)
