"""``[downtime]``: the reasons an operator picks for a stop, and from how long a stop asks for
one (docs/dashboard.md#downtime-reasons). The stops and the lost time per reason are
:mod:`opendnc.server.utilization.downtime`'s."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from opendnc.server.core.configkeys import ConfigError, get_key, known_keys

__all__ = ["DEFAULT_REASONS", "NO_REASON", "STOP_MIN", "DowntimeConfig", "parse_downtime"]

STOP_MIN = 300.0  # seconds: shorter pauses are part of the work (a tool change, a part swap)

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
