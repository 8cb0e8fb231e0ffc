"""The one vocabulary of the server's open outputs: MTConnect data items per machine.

The MQTT publisher and the MTConnect SHDR adapter both turn the machines' status events
(:class:`~opendnc.server.core.events.MachineStatusChanged`) into these items, keep each item's last
value with the time it changed, and report only what changed (docs/server.md#open-outputs).
An unknown value is ``None``: MTConnect's UNAVAILABLE, MQTT's ``quality: "unavailable"``.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from datetime import UTC, datetime

from opendnc.server.core.events import MachineStatusChanged
from opendnc.server.core.state import State

__all__ = [
    "ITEMS",
    "SERVER_STOPPED",
    "ItemSpec",
    "ItemTracker",
    "Reading",
    "Value",
    "controller_mode",
    "items_of",
    "shdr_time",
]

SERVER_STOPPED = "the opendnc server stopped"
"""The message every output leaves with each machine when the server stops cleanly."""

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


def _number(value: float | None, *, positive: bool = False) -> int | float | None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    if positive and value <= 0:
        return None
    return value


def items_of(event: MachineStatusChanged | None) -> dict[str, Value]:
    """Every item's value from a machine's status event (None: nothing known yet).

    Availability is the classifier's: a machine it calls offline is UNAVAILABLE, every other
    state (unknown included: the control answers but does not say what it does) AVAILABLE.
    """
    values: dict[str, Value] = {spec.key: None for spec in ITEMS}
    status = event.status if event is not None else None
    if event is None or status is None or event.state is State.OFFLINE:
        values["availability"] = "UNAVAILABLE"
        # The reason the server cannot reach the control is the one thing known about it.
        if event is not None:
            values["message"] = (status.message if status else "") or event.last_error or None
        return values
    execution = status.execution
    overrides = status.overrides
    values.update(
        availability="AVAILABLE",
        execution=execution if execution in _EXECUTION else None,
        controller_mode=controller_mode(status.mode),
        program=status.program or None,
        # Program lines count from 1: a 0 is a control that does not tell.
        line_number=_number(status.line, positive=True),
        part_count=_number(status.part_count),
        tool_number=_number(status.tool),
        feed_override=_number(overrides.get("feed")),
        rapid_override=_number(overrides.get("rapid")),
        spindle_override=_number(overrides.get("spindle")),
        message=status.message or None,
        system=tuple(status.errors),
    )
    return values


@dataclass(frozen=True)
class Reading:
    """An item's value and when it took that value."""

    value: Value
    timestamp: datetime


class ItemTracker:
    """The last reading of every item of every machine: the state an output sends whole on
    connect, and the changes it reports by exception.

    Until its first status event a machine is *not known*: its items read UNAVAILABLE, as an
    agent marks them, but an output that retains what it publishes (MQTT) waits for the first
    event rather than announcing UNAVAILABLE and then AVAILABLE a moment later.
    """

    def __init__(self, machines: Iterable[str]) -> None:
        start = datetime.now(UTC)
        first = {key: Reading(value, start) for key, value in items_of(None).items()}
        self._state: dict[str, dict[str, Reading]] = {name: dict(first) for name in machines}
        self._known: dict[str, State] = {}

    @property
    def machines(self) -> list[str]:
        """The machines tracked, in configuration order."""
        return list(self._state)

    def known(self, machine: str) -> bool:
        """Whether ``machine``'s status has been read since the server started."""
        return machine in self._known

    def state(self, machine: str) -> State | None:
        """The classifier's state of ``machine`` at its last event (None: not known yet)."""
        return self._known.get(machine)

    def forget(self, machine: str) -> None:
        """No longer known here (another server of a cluster serves it now): not in the
        whole state a reconnect sends, nor made unavailable by a stop."""
        self._known.pop(machine, None)

    def snapshot(self, machine: str) -> dict[str, Reading]:
        """Every item of ``machine`` as last seen."""
        return dict(self._state[machine])

    def update(self, event: MachineStatusChanged) -> dict[str, Reading]:
        """Take a status event; the items whose value changed (empty if none did)."""
        readings = self._state.get(event.machine)
        if readings is None:
            return {}
        self._known[event.machine] = event.state
        at = event.status.at if event.status is not None else datetime.now(UTC)
        at = at if at.tzinfo is not None else at.replace(tzinfo=UTC)
        changed: dict[str, Reading] = {}
        for key, value in items_of(event).items():
            if readings[key].value != value:
                readings[key] = changed[key] = Reading(value, at)
        return changed

    def stopped(
        self, message: str, machines: Iterable[str] | None = None
    ) -> dict[str, dict[str, Reading]]:
        """The server stops (or no longer serves ``machines``): every known machine (of
        those) becomes unavailable with ``message``; the items that changed, per machine."""
        at = datetime.now(UTC)
        out: dict[str, dict[str, Reading]] = {}
        wanted = list(self._known) if machines is None else list(machines)
        for machine in [m for m in wanted if m in self._known]:
            readings = self._state[machine]
            values = items_of(None)
            values["message"] = message
            changed = {}
            for key, value in values.items():
                if readings[key].value != value:
                    readings[key] = changed[key] = Reading(value, at)
            self._known[machine] = State.OFFLINE
            out[machine] = changed
        return out


def shdr_time(at: datetime) -> str:
    """A UTC timestamp as SHDR and MQTT payloads carry it (ISO 8601, ``Z``)."""
    return at.astimezone(UTC).strftime("%Y-%m-%dT%H:%M:%S.%fZ")
