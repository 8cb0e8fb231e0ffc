"""Downtime reasons: the list ``[downtime]`` configures, the stops that ask for one, and the
lost time per reason (the Pareto) (docs/dashboard.md#downtime-reasons).

A stop is what :mod:`.sums` calls one: 5 minutes or more not running, consecutive states
joined. Its reason is stored against the machine and the instant the stop began
(``downtime_reasons``), which is what names a stop across the summed hours and the samples.
Stops longer than ``[downtime] threshold`` seconds ask an operator for a reason.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from datetime import datetime
from typing import Any

from sqlalchemy import select
from sqlalchemy.orm import Session

from opendnc.server.configkeys import ConfigError, get_key, known_keys
from opendnc.server.store.models import DowntimeReason
from opendnc.server.utilization.sums import STOP_MIN, Stretch, as_utc

__all__ = [
    "DEFAULT_REASONS",
    "NO_REASON",
    "DowntimeConfig",
    "ParetoRow",
    "StopWithReason",
    "pareto",
    "parse_downtime",
    "reasons_for",
    "with_reasons",
]

DEFAULT_REASONS = (
    "no operator",
    "material",
    "tool change",
    "setup",
    "maintenance",
    "waiting for program",
    "quality check",
    "other",
)
NO_REASON = "no reason given"


@dataclass(frozen=True)
class DowntimeConfig:
    """``[downtime]``: the reasons an operator picks from, and from how many seconds on a
    stop asks for one (never below a stop's own 5 minutes: shorter pauses are no stop)."""

    reasons: tuple[str, ...] = DEFAULT_REASONS
    threshold: float = STOP_MIN


def parse_downtime(table: dict[str, Any]) -> DowntimeConfig:
    """``[downtime]`` checked; :class:`ConfigError` names the bad key."""
    known_keys(table, "downtime", {"reasons", "threshold"})
    raw = get_key(table, "downtime", "reasons", list, list(DEFAULT_REASONS))
    reasons: list[str] = []
    for i, item in enumerate(raw):
        if not isinstance(item, str) or not item.strip() or len(item.strip()) > 64:
            raise ConfigError(f"downtime.reasons[{i}]", "expected a name of 1 to 64 characters")
        name = item.strip()
        if name.lower() in (r.lower() for r in reasons):
            raise ConfigError(f"downtime.reasons[{i}]", f"{name!r} is listed twice")
        if name.lower() == NO_REASON:
            raise ConfigError(f"downtime.reasons[{i}]", f"{NO_REASON!r} is the Pareto's own")
        reasons.append(name)
    if not reasons:
        raise ConfigError("downtime.reasons", "expected at least one reason")
    threshold = get_key(table, "downtime", "threshold", float, STOP_MIN)
    if threshold < STOP_MIN:
        raise ConfigError(
            "downtime.threshold", f"expected {STOP_MIN:.0f} seconds or more (a stop's least)"
        )
    return DowntimeConfig(tuple(reasons), threshold)


@dataclass(frozen=True)
class StopWithReason:
    """A stop and the reason picked for it ("" while none is)."""

    machine: str
    stop: Stretch
    reason: str = ""
    note: str = ""
    by: str = ""

    @property
    def seconds(self) -> float:
        """The stop's length."""
        return self.stop.seconds


def reasons_for(
    session: Session, machines: Sequence[str], start: datetime, end: datetime
) -> dict[tuple[str, datetime], DowntimeReason]:
    """The reasons picked for stops of ``machines`` that began in ``[start, end)``, by
    (machine, start)."""
    if not machines:
        return {}
    rows = session.scalars(
        select(DowntimeReason).where(
            DowntimeReason.machine.in_(machines),
            DowntimeReason.start >= start,
            DowntimeReason.start < end,
        )
    )
    return {(r.machine, as_utc(r.start)): r for r in rows}


def with_reasons(
    machine: str, stops: Iterable[Stretch], picked: dict[tuple[str, datetime], DowntimeReason]
) -> list[StopWithReason]:
    """``stops`` of ``machine`` with the reasons picked for them."""
    out = []
    for s in stops:
        row = picked.get((machine, s.start))
        if row is None:
            out.append(StopWithReason(machine, s))
        else:
            out.append(StopWithReason(machine, s, row.reason, row.note, row.by))
    return out


@dataclass
class ParetoRow:
    """Lost time for one reason: how many stops, how long, its share of all stop time and
    the running share (the Pareto's line)."""

    reason: str
    stops: int = 0
    seconds: float = 0.0
    share: float = 0.0
    cumulative: float = 0.0
    machines: set[str] = field(default_factory=set)


def pareto(stops: Iterable[StopWithReason]) -> list[ParetoRow]:
    """Lost time per reason, longest first (stops without a reason as :data:`NO_REASON`,
    always last, so what is still to be explained is seen apart)."""
    rows: dict[str, ParetoRow] = {}
    for s in stops:
        name = s.reason or NO_REASON
        row = rows.setdefault(name, ParetoRow(name))
        row.stops += 1
        row.seconds += s.seconds
        row.machines.add(s.machine)
    ordered = sorted(rows.values(), key=lambda r: (r.reason == NO_REASON, -r.seconds, r.reason))
    total = sum(r.seconds for r in ordered)
    running = 0.0
    for r in ordered:
        running += r.seconds
        r.share = 100.0 * r.seconds / total if total else 0.0
        r.cumulative = 100.0 * running / total if total else 0.0
    return ordered
