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

from sqlalchemy import select
from sqlalchemy.orm import Session

from opendnc.server.config.downtime import NO_REASON
from opendnc.server.store.models import DowntimeReason
from opendnc.server.utilization.sums import Stretch, as_utc

__all__ = [
    "ParetoRow",
    "StopWithReason",
    "order_pareto",
    "pareto",
    "reasons_for",
    "with_reasons",
]


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
    return order_pareto(rows.values())


def order_pareto(rows: Iterable[ParetoRow]) -> list[ParetoRow]:
    """``rows`` longest first, :data:`NO_REASON` last, with their shares filled in."""
    ordered = sorted(rows, key=lambda r: (r.reason == NO_REASON, -r.seconds, r.reason))
    total = sum(r.seconds for r in ordered)
    running = 0.0
    for r in ordered:
        running += r.seconds
        r.share = 100.0 * r.seconds / total if total else 0.0
        r.cumulative = 100.0 * running / total if total else 0.0
    return ordered
