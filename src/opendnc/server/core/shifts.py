"""The shop's calendar: its time zone and its shifts, from ``[server] timezone`` and ``[[shifts]]``.

Utilization is read per shift, per day and per week of the shop's own clock, so every boundary
is a local wall-clock time turned into an instant through :mod:`zoneinfo`. That makes a day
23 or 25 hours long when the clocks change, and an overnight shift 22:00-06:00 one hour
shorter in spring and one hour longer in autumn, as the people working it experience
(docs/server.md#shifts)::

    [server]
    timezone = "Europe/Berlin"

    [[shifts]]
    name = "early"
    days = ["mon-fri"]          # the days the shift starts on
    start = "06:00"
    end = "14:00"

    [[shifts]]
    name = "night"
    days = ["mon", "tue", "wed", "thu", "fri"]
    start = "22:00"
    end = "06:00"               # before the start: it ends the next day

A wall-clock start that does not exist (inside the spring gap) is read with the offset before
the change, and one that exists twice (the autumn hour) as its first occurrence (PEP 495
``fold=0``).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from datetime import UTC, date, datetime, time, timedelta, tzinfo
from typing import Any
from zoneinfo import ZoneInfo, ZoneInfoNotFoundError

from opendnc.errors import InputError

__all__ = ["DAYS", "Calendar", "Period", "Shift", "parse_calendar"]

DAYS = ("mon", "tue", "wed", "thu", "fri", "sat", "sun")
_CLOCK = re.compile(r"([01]?\d|2[0-3]):([0-5]\d)|24:00")


class CalendarError(InputError):
    """``[[shifts]]`` or ``[server] timezone`` is malformed; the message names the key."""


@dataclass(frozen=True)
class Shift:
    """A shift starting at ``start`` on each of ``days`` (0 = Monday) in the shop's zone."""

    name: str
    days: frozenset[int]
    start: time
    end: time  # at or before ``start``: the shift ends the next day
    ends_at_midnight: bool = False  # end = "24:00"

    @property
    def overnight(self) -> bool:
        """True if the shift ends on the day after it starts."""
        return self.ends_at_midnight or self.end <= self.start


@dataclass(frozen=True)
class Period:
    """One shift, day or week of the shop's clock, as UTC instants ``[start, end)``."""

    key: str  # "2026-03-29 night", "2026-03-29", "2026-W13"
    start: datetime
    end: datetime
    shift: str = ""  # the shift's name for a shift period

    @property
    def seconds(self) -> float:
        """The period's real length (a DST day is 23 or 25 hours)."""
        return (self.end - self.start).total_seconds()


@dataclass(frozen=True)
class Calendar:
    """The shop's zone and shifts. Without shifts every hour counts as scheduled."""

    zone: tzinfo = UTC
    shifts: tuple[Shift, ...] = field(default=())

    @property
    def zone_name(self) -> str:
        """The zone's IANA name (``Europe/Berlin``), as people configure it."""
        return str(getattr(self.zone, "key", None) or self.zone.tzname(None) or "UTC")

    def instant(self, day: date, clock: time) -> datetime:
        """The UTC instant of wall-clock ``clock`` on local ``day``."""
        return datetime.combine(day, clock, tzinfo=self.zone).astimezone(UTC)

    def local(self, at: datetime) -> datetime:
        """``at`` on the shop's clock."""
        return at.astimezone(self.zone)

    def _days(self, start: datetime, end: datetime) -> list[date]:
        # One day early: an overnight shift that began the day before reaches into the span.
        first = self.local(start).date() - timedelta(days=1)
        last = self.local(end).date()
        return [first + timedelta(days=i) for i in range((last - first).days + 1)]

    def shift_periods(self, start: datetime, end: datetime) -> list[Period]:
        """Every shift worked (in part) within ``[start, end)``, in time order."""
        out: list[Period] = []
        for day in self._days(start, end):
            for shift in self.shifts:
                if day.weekday() not in shift.days:
                    continue
                begin = self.instant(day, shift.start)
                end_day = day + timedelta(days=1) if shift.overnight else day
                until = self.instant(end_day, time(0) if shift.ends_at_midnight else shift.end)
                if until > start and begin < end:
                    out.append(Period(f"{day.isoformat()} {shift.name}", begin, until, shift.name))
        out.sort(key=lambda p: (p.start, p.key))
        return out

    def day_periods(self, start: datetime, end: datetime) -> list[Period]:
        """The shop's days (local midnight to midnight) that overlap ``[start, end)``."""
        out = []
        for day in self._days(start, end):
            begin = self.instant(day, time(0))
            until = self.instant(day + timedelta(days=1), time(0))
            if until > start and begin < end:
                out.append(Period(day.isoformat(), begin, until))
        return out

    def week_periods(self, start: datetime, end: datetime) -> list[Period]:
        """The ISO weeks (local Monday 00:00 to Monday 00:00) that overlap ``[start, end)``."""
        out: list[Period] = []
        first = self._days(start, end)[0]
        monday = first - timedelta(days=first.weekday())
        while True:
            begin = self.instant(monday, time(0))
            if begin >= end:
                return out
            until = self.instant(monday + timedelta(days=7), time(0))
            year, week, _ = monday.isocalendar()
            if until > start:
                out.append(Period(f"{year}-W{week:02d}", begin, until))
            monday += timedelta(days=7)

    def scheduled(self, start: datetime, end: datetime) -> list[tuple[datetime, datetime]]:
        """The shift time within ``[start, end)`` as merged UTC intervals; all of it without
        shifts (a shop that configures none runs around the clock)."""
        if not self.shifts:
            return [(start, end)] if end > start else []
        merged: list[tuple[datetime, datetime]] = []
        for p in self.shift_periods(start, end):
            a, b = max(p.start, start), min(p.end, end)
            if b <= a:
                continue
            if merged and a <= merged[-1][1]:
                merged[-1] = (merged[-1][0], max(merged[-1][1], b))
            else:
                merged.append((a, b))
        return merged


def parse_calendar(raw: dict[str, Any]) -> Calendar:
    """The calendar of a parsed ``shop.toml`` (its ``[server] timezone`` and ``[[shifts]]``);
    :class:`CalendarError` names the first bad key."""
    server = raw.get("server", {})
    zone_name = server.get("timezone", "UTC") if isinstance(server, dict) else "UTC"
    if not isinstance(zone_name, str) or not zone_name:
        raise CalendarError(f"server.timezone: expected a zone name, got {zone_name!r}")
    try:
        zone = ZoneInfo(zone_name)
    except (ZoneInfoNotFoundError, ValueError):
        # Windows has no zone database of its own: the tzdata package brings it.
        raise CalendarError(
            f"server.timezone: unknown time zone {zone_name!r} (an IANA name like "
            "'Europe/Berlin'; on Windows install tzdata)"
        ) from None
    items = raw.get("shifts", [])
    if not isinstance(items, list):
        raise CalendarError("shifts: expected an array of tables ([[shifts]])")
    shifts = tuple(_shift(item, f"shifts[{i}]") for i, item in enumerate(items))
    names = [s.name.lower() for s in shifts]
    for i, name in enumerate(names):
        if name in names[:i]:
            raise CalendarError(f"shifts[{i}].name: {shifts[i].name!r} is used twice")
    return Calendar(zone, shifts)


def _shift(item: Any, prefix: str) -> Shift:
    if not isinstance(item, dict):
        raise CalendarError(f"{prefix}: expected a table")
    for key in item:
        if key not in ("name", "days", "start", "end"):
            raise CalendarError(
                f"{prefix}.{key}: unknown key (expected one of days, end, name, start)"
            )
    name = item.get("name")
    if not isinstance(name, str) or not re.fullmatch(r"[\w .-]{1,32}", name):
        raise CalendarError(f"{prefix}.name: expected a short name like 'early', got {name!r}")
    days = _days(item.get("days", ["mon-fri"]), f"{prefix}.days")
    start, late = _clock(item.get("start"), f"{prefix}.start")
    if late:
        raise CalendarError(f"{prefix}.start: a shift starts at 00:00 to 23:59, not 24:00")
    end, midnight = _clock(item.get("end"), f"{prefix}.end")
    if start == end and not midnight:
        raise CalendarError(f"{prefix}.end: the same as the start (a shift of no length)")
    if midnight and start == time(0):
        raise CalendarError(f"{prefix}.end: 00:00 to 24:00 is a whole day: use 00:00 to 00:00")
    return Shift(name, days, start, end, midnight)


def _clock(value: Any, key: str) -> tuple[time, bool]:
    if not isinstance(value, str) or not _CLOCK.fullmatch(value.strip()):
        raise CalendarError(f"{key}: expected HH:MM (24 h), got {value!r}")
    text = value.strip()
    if text == "24:00":
        return time(0), True
    hours, minutes = text.split(":")
    return time(int(hours), int(minutes)), False


def _days(value: Any, key: str) -> frozenset[int]:
    if isinstance(value, str):
        value = [value]
    if not isinstance(value, list) or not value:
        raise CalendarError(f'{key}: expected a list like ["mon-fri"] or ["sat"]')
    out: set[int] = set()
    for item in value:
        text = item.strip().lower()[:3] if isinstance(item, str) and "-" not in item else item
        if isinstance(item, str) and "-" in item:
            first, _, last = item.lower().partition("-")
            if first.strip()[:3] not in DAYS or last.strip()[:3] not in DAYS:
                raise CalendarError(f"{key}: expected day names like mon-fri, got {item!r}")
            a, b = DAYS.index(first.strip()[:3]), DAYS.index(last.strip()[:3])
            out.update(range(a, b + 1) if a <= b else [*range(a, 7), *range(0, b + 1)])
        elif isinstance(text, str) and text in DAYS:
            out.add(DAYS.index(text))
        else:
            raise CalendarError(f"{key}: expected day names (mon, tue, ... sun), got {item!r}")
    return frozenset(out)
