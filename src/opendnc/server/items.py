"""The one vocabulary of the server's open outputs: MTConnect data items per machine.

The MQTT publisher and the MTConnect SHDR adapter both turn the supervisor's ``machine``
events into these items, keep each item's last value with the time it changed, and report
only what changed (docs/server.md#open-outputs). An unknown value is ``None``: MTConnect's
UNAVAILABLE, MQTT's ``quality: "unavailable"``.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

__all__ = [
    "ITEMS",
    "ItemSpec",
    "ItemTracker",
    "Reading",
    "Value",
    "controller_mode",
    "items_of",
    "shdr_time",
]

Value = str | int | float | tuple[str, ...] | None
"""An item's value: a condition's is the tuple of active faults; None is UNAVAILABLE."""


@dataclass(frozen=True)
class ItemSpec:
    """One data item: its key (SHDR key, MQTT topic level) and its MTConnect type."""

    key: str
    type: str
    category: str = "EVENT"  # EVENT, SAMPLE or CONDITION
    sub_type: str = ""
    units: str = ""
    component: str = "path"  # where it sits in the device model: device, controller, path


ITEMS: tuple[ItemSpec, ...] = (
    ItemSpec("availability", "AVAILABILITY", component="device"),
    ItemSpec("execution", "EXECUTION"),
    ItemSpec("controller_mode", "CONTROLLER_MODE", component="controller"),
    ItemSpec("program", "PROGRAM"),
    ItemSpec("line_number", "LINE_NUMBER", sub_type="ABSOLUTE"),
    ItemSpec("part_count", "PART_COUNT"),
    ItemSpec("tool_number", "TOOL_NUMBER"),
    ItemSpec("feed_override", "PATH_FEEDRATE_OVERRIDE", sub_type="PROGRAMMED", units="PERCENT"),
    ItemSpec("rapid_override", "PATH_FEEDRATE_OVERRIDE", sub_type="RAPID", units="PERCENT"),
    ItemSpec("spindle_override", "ROTARY_VELOCITY_OVERRIDE", units="PERCENT"),
    ItemSpec("message", "MESSAGE", component="controller"),
    ItemSpec("system", "SYSTEM", category="CONDITION", component="controller"),
)

_EXECUTION = {
    "READY", "ACTIVE", "INTERRUPTED", "FEED_HOLD", "STOPPED", "OPTIONAL_STOP",
    "PROGRAM_STOPPED", "PROGRAM_COMPLETED", "WAIT",
}  # fmt: skip
# The connectors already speak MTConnect's CONTROLLER_MODE (machines/base.py): anything else
# is a mode not known, UNAVAILABLE.
_MODES = {"AUTOMATIC", "MANUAL", "MANUAL_DATA_INPUT", "SEMI_AUTOMATIC", "EDIT"}


def controller_mode(mode: str) -> str | None:
    """MTConnect's CONTROLLER_MODE for a status's ``mode``; None when it is not one."""
    return mode if mode in _MODES else None


def _number(value: Any, *, positive: bool = False) -> int | float | None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    if positive and value <= 0:
        return None
    return value


def items_of(machine: Mapping[str, Any]) -> dict[str, Value]:
    """Every item's value from a ``machine`` event (``MachineState.as_json()``)."""
    status = machine.get("status") or {}
    values: dict[str, Value] = {spec.key: None for spec in ITEMS}
    if not machine.get("online") or not status.get("available"):
        values["availability"] = "UNAVAILABLE"
        # The reason the server cannot reach the control is the one thing known about it.
        values["message"] = str(status.get("message") or machine.get("last_error") or "") or None
        return values
    execution = str(status.get("execution") or "")
    overrides = status.get("overrides") or {}
    values.update(
        availability="AVAILABLE",
        execution=execution if execution in _EXECUTION else None,
        controller_mode=controller_mode(str(status.get("mode") or "")),
        program=str(status.get("program") or "") or None,
        # Program lines count from 1: a 0 is a control that does not tell.
        line_number=_number(status.get("line"), positive=True),
        part_count=_number(status.get("part_count")),
        tool_number=_number(status.get("tool")),
        feed_override=_number(overrides.get("feed")),
        rapid_override=_number(overrides.get("rapid")),
        spindle_override=_number(overrides.get("spindle")),
        message=str(status.get("message") or "") or None,
        system=tuple(str(e) for e in status.get("errors") or ()),
    )
    return values


@dataclass(frozen=True)
class Reading:
    """An item's value and when it took that value."""

    value: Value
    timestamp: datetime


def _parse_time(text: Any) -> datetime | None:
    if not isinstance(text, str):
        return None
    try:
        at = datetime.fromisoformat(text)
    except ValueError:
        return None
    return at if at.tzinfo is not None else at.replace(tzinfo=UTC)


class ItemTracker:
    """The last reading of every item of every machine: the state an output sends whole on
    connect, and the changes it reports by exception."""

    def __init__(self, machines: Iterable[str]) -> None:
        start = datetime.now(UTC)
        # Until its first status read a machine is unavailable, as an agent marks it.
        first = {key: Reading(value, start) for key, value in items_of({}).items()}
        self._state: dict[str, dict[str, Reading]] = {name: dict(first) for name in machines}

    @property
    def machines(self) -> list[str]:
        """The machines tracked, in configuration order."""
        return list(self._state)

    def snapshot(self, machine: str) -> dict[str, Reading]:
        """Every item of ``machine`` as last seen."""
        return dict(self._state[machine])

    def update(self, machine: str, data: Mapping[str, Any]) -> dict[str, Reading]:
        """Take a ``machine`` event; the items whose value changed (empty if none did)."""
        readings = self._state.get(machine)
        if readings is None:
            return {}
        status = data.get("status") or {}
        at = _parse_time(status.get("at")) or datetime.now(UTC)
        changed: dict[str, Reading] = {}
        for key, value in items_of(data).items():
            if readings[key].value != value:
                readings[key] = changed[key] = Reading(value, at)
        return changed


def shdr_time(at: datetime) -> str:
    """A UTC timestamp as SHDR and MQTT payloads carry it (ISO 8601, ``Z``)."""
    return at.astimezone(UTC).strftime("%Y-%m-%dT%H:%M:%S.%fZ")
