"""``[goals]``: the parts a supervisor expects of a machine, per shift or per day
(docs/dashboard.md#goals)::

    [goals]
    "vf2" = { shift = 40 }                       # every shift: 40 parts
    "mill-1" = { shift = { early = 30, late = 24 } }  # per named shift (others: none)
    "lathe-3" = { day = 120 }                    # per day, spread over the day's shift time

A goal counts over any piece of time in proportion to the planned time of it: a shift's goal
over the part of the shift that lies in the piece, a day's goal over the part of the day's
shift time (the whole day in a shop without shifts). So "expected by now" is the goal of the
shift's start up to now, and a day's goal is the sum of its shifts'. A machine without a goal
here gets the pace of its standard times (:mod:`opendnc.server.utilization.oee`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import datetime, timedelta
from typing import Any

from opendnc.server.core.configkeys import ConfigError
from opendnc.server.core.shifts import Calendar

__all__ = ["MAX_GOAL", "Goal", "GoalsConfig", "parse_goals"]

MAX_GOAL = 1_000_000  # parts in one shift or day: more is a typing slip


@dataclass(frozen=True)
class Goal:
    """One machine's goal: parts per shift (one number for every shift, or per shift name)
    or parts per day."""

    per_shift: int | None = None
    by_shift: dict[str, int] = field(default_factory=dict)  # shift name (lower case) -> parts
    per_day: int | None = None

    def over(self, calendar: Calendar, start: datetime, end: datetime) -> float:
        """The parts this goal asks for within ``[start, end)`` (a fraction of a shift's or a
        day's goal for the part of it inside)."""
        if end <= start:
            return 0.0
        if self.per_day is not None:
            return self._days(calendar, start, end)
        total = 0.0
        for p in calendar.shift_periods(start, end):
            parts = self.by_shift.get(p.shift.lower(), self.per_shift)
            if not parts:
                continue
            inside = (min(p.end, end) - max(p.start, start)).total_seconds()
            if inside > 0:
                total += parts * inside / p.seconds
        return total

    def _days(self, calendar: Calendar, start: datetime, end: datetime) -> float:
        assert self.per_day is not None
        total = 0.0
        for day in calendar.day_periods(start, end):
            planned = _seconds(calendar.scheduled(day.start, day.end))
            if planned <= 0:
                continue  # a day without shifts asks for nothing
            inside = _seconds(calendar.scheduled(max(day.start, start), min(day.end, end)))
            total += self.per_day * inside / planned
        return total


def _seconds(spans: list[tuple[datetime, datetime]]) -> float:
    return sum(((b - a) for a, b in spans), timedelta()).total_seconds()


@dataclass(frozen=True)
class GoalsConfig:
    """``[goals]``: each machine's goal (machines not named have none)."""

    machines: dict[str, Goal] = field(default_factory=dict)

    def of(self, machine: str) -> Goal | None:
        """The machine's goal, or None."""
        return self.machines.get(machine)


def _count(value: Any, key: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 0 < value <= MAX_GOAL:
        raise ConfigError(key, f"expected a number of parts, 1 to {MAX_GOAL}, got {value!r}")
    return value


def parse_goals(table: dict[str, Any], machines: set[str], calendar: Calendar) -> GoalsConfig:
    """``[goals]`` checked against the configured machines and shifts; :class:`ConfigError`
    names the bad key."""
    shifts = {s.name.lower() for s in calendar.shifts}
    out: dict[str, Goal] = {}
    for name, item in table.items():
        prefix = f"goals.{name}"
        if name not in machines:
            raise ConfigError(prefix, "no machine of that name is configured")
        if not isinstance(item, dict) or len(item) != 1 or next(iter(item)) not in ("shift", "day"):
            raise ConfigError(
                prefix, "expected { shift = N }, { shift = { NAME = N } } or { day = N }"
            )
        if "day" in item:
            out[name] = Goal(per_day=_count(item["day"], f"{prefix}.day"))
            continue
        if not shifts:
            raise ConfigError(f"{prefix}.shift", "a goal per shift needs [[shifts]]")
        value = item["shift"]
        if isinstance(value, dict):
            by: dict[str, int] = {}
            for shift, parts in value.items():
                if shift.lower() not in shifts:
                    raise ConfigError(f"{prefix}.shift.{shift}", "no shift of that name")
                by[shift.lower()] = _count(parts, f"{prefix}.shift.{shift}")
            out[name] = Goal(by_shift=by)
        else:
            out[name] = Goal(per_shift=_count(value, f"{prefix}.shift"))
    return GoalsConfig(out)
