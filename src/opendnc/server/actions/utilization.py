"""Utilization read actions: the API's report and the utilization page's figures
(docs/dashboard.md#utilization).

Each first sums the hours that finished since the last summing (a short write), then answers
from a read-only transaction (on SQLite it does not hold the write lock meanwhile), so the API
and the page give the same figures for the same question.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import UTC, date, datetime, time, timedelta

from opendnc.server.actions.base import Caller, Services, require
from opendnc.server.core.shifts import Period
from opendnc.server.store.models import Role
from opendnc.server.utilization.answer import full_report, run_report
from opendnc.server.utilization.collect import (
    Figures,
    Group,
    Report,
    buckets,
    equal_periods,
    sum_safely,
)
from opendnc.server.utilization.oee import Oee

__all__ = [
    "Glance",
    "ShopFigures",
    "current_shift",
    "days_report",
    "floor_glance",
    "report_for",
    "shop_figures",
]


@dataclass(frozen=True)
class ShopFigures:
    """What the utilization page draws: the report, and each machine's figures per slice of
    the span up to now (its Gantt)."""

    report: Report
    slices: list[Period]
    figures: dict[str, list[Figures]]


def report_for(
    svc: Services,
    who: Caller,
    *,
    start: str | None,
    end: str | None,
    machines: list[str] | None,
    group: str,
) -> Report:
    """The API's question as it was typed (``from``, ``to``, machines, grouping), parsed and
    answered (viewers; :class:`~opendnc.errors.InputError` for a bad parameter)."""
    require(who, Role.VIEWER)
    config = svc.runner.config
    return run_report(svc.sessions, config, start=start, end=end, machines=machines, group=group)


def _sum_finished(svc: Services, names: list[str], now: datetime) -> None:
    # short: what finished since the last summing
    svc.write(lambda s: sum_safely(s, names, now, svc.runner.config.calendar))


def days_report(
    svc: Services,
    who: Caller,
    first: date,
    last: date,
    group: Group,
    names: list[str],
    now: datetime | None = None,
) -> Report:
    """The report over whole local days ``first`` to ``last`` (both included; viewers)."""
    require(who, Role.VIEWER)
    now = now or datetime.now(UTC)
    cal = svc.runner.config.calendar
    start, end = cal.instant(first, time(0)), cal.instant(last + timedelta(days=1), time(0))
    # the figures every page and the shift report read, OEE and reasons with them
    return full_report(svc.sessions, svc.runner.config, names, start, end, group, now)


def shop_figures(
    svc: Services,
    who: Caller,
    first: date,
    last: date,
    group: Group,
    names: list[str],
    step: timedelta,
    now: datetime | None = None,
) -> ShopFigures:
    """The report over whole local days and each machine's figures per ``step`` up to now
    (at least five minutes in; viewers)."""
    require(who, Role.VIEWER)
    now = now or datetime.now(UTC)
    cal = svc.runner.config.calendar
    start, end = cal.instant(first, time(0)), cal.instant(last + timedelta(days=1), time(0))
    r = full_report(svc.sessions, svc.runner.config, names, start, end, group, now)
    with svc.reads() as session:
        shown_end = min(end, max(start + timedelta(minutes=5), now))
        slices = equal_periods(start, shown_end, step)
        figures = buckets(session, names, slices, now=now, sum_first=False)
    return ShopFigures(r, slices, figures)


@dataclass(frozen=True)
class Glance:
    """One machine at a glance (its card): the shift now with its parts against the goal,
    and today so far. Both are :func:`days_report`'s and :func:`.answer.full_report`'s
    figures, the ones the utilization page and the shift report show."""

    machine: str
    shift: Period | None  # the shift under way (None between shifts or without shifts)
    shift_oee: Oee | None
    today: Figures
    today_oee: Oee


def current_shift(svc: Services, now: datetime) -> Period | None:
    """The shift under way at ``now`` (the one that began last, should two overlap)."""
    cal = svc.runner.config.calendar
    under_way = [
        p for p in cal.shift_periods(now - timedelta(days=1), now + timedelta(seconds=1))
        if p.start <= now < p.end
    ]  # fmt: skip
    return under_way[-1] if under_way else None


def floor_glance(
    svc: Services, who: Caller, names: list[str], now: datetime | None = None
) -> dict[str, Glance]:
    """Each machine's glance (viewers): today as the utilization page reads it, and the
    shift under way as the shift report reads it."""
    require(who, Role.VIEWER)
    now = now or datetime.now(UTC)
    today = svc.runner.config.calendar.local(now).date()
    day = days_report(svc, who, today, today, Group.DAY, names, now)
    shift = current_shift(svc, now)
    during = None
    if shift is not None:
        config = svc.runner.config
        during = full_report(svc.sessions, config, names, shift.start, shift.end, Group.SHIFT, now)
    out: dict[str, Glance] = {}
    for m in day.machines:
        mf = day.floor.of(m.machine)
        sf = during.floor.of(m.machine) if during is not None else None
        out[m.machine] = Glance(
            m.machine, shift, sf.totals if sf is not None else None, m.totals, mf.totals
        )
    return out
