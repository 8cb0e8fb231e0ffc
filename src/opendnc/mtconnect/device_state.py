"""One device's state as an agent reports it: sans-IO, fed documents (docs/mtconnect-input.md).

:class:`DeviceState` learns from a probe which data items mean what (by ``type``, whatever
the agent calls them), takes a ``current`` answer whole (:meth:`DeviceState.load`) and the
observations of ``sample`` answers one by one (:meth:`DeviceState.update`), and tells the
latest values as a :class:`Snapshot` in MTConnect's own words.

Counters are the agent's values, never sums of what was seen: PartCount is the control's
count, so an observation read twice (a resumed stream, an agent restart that resends every
value, a ``current`` after a gap) leaves it as it was. Sample observations at or below the
last sequence taken are dropped all the same (an agent may resend around a reconnect).
"""

from __future__ import annotations

from dataclasses import dataclass

from opendnc.errors import RemoteProtocolError
from opendnc.mtconnect.documents import UNAVAILABLE, DataItem, Devices, Observation, Streams

__all__ = ["DeviceState", "Snapshot", "pick_device"]

# Types whose value the snapshot reports, by snapshot field. Older agents (1.x) name the line
# type LINE; 1.4 and later LINE_NUMBER.
_FIELDS = {
    "AVAILABILITY": "availability",
    "EXECUTION": "execution",
    "CONTROLLER_MODE": "controller_mode",
    "EMERGENCY_STOP": "emergency_stop",
    "PROGRAM": "program",
    "LINE_NUMBER": "line",
    "LINE": "line",
    "PART_COUNT": "part_count",
    "TOOL_NUMBER": "tool",
    "MESSAGE": "message",
}
# PartCount subtypes that are not the count of parts made (targets and what is left).
_NOT_THE_COUNT = frozenset({"TARGET", "REMAINING", "BAD", "GOOD", "FAILED", "REJECT"})
# LineNumber subtypes: INCREMENTAL counts lines since the last reset, not the program's line.
_NOT_THE_LINE = frozenset({"INCREMENTAL"})
# The largest line, part count or tool number reported: the status timeline's Integer column.
MAX_NUMBER = 2**31 - 1


@dataclass(frozen=True)
class Snapshot:
    """The device's latest values; None where the agent reads UNAVAILABLE or has no item."""

    availability: str | None = None
    execution: str | None = None
    controller_mode: str | None = None
    emergency_stop: str | None = None
    program: str | None = None
    line: int | None = None
    part_count: int | None = None
    tool: int | None = None
    message: str | None = None
    faults: tuple[str, ...] = ()  # active Fault conditions: "nativeCode text" or the type
    warnings: tuple[str, ...] = ()


def pick_device(devices: Devices, name: str) -> str:
    """The device ``name`` of a probe, or its only device when ``name`` is empty."""
    names = [d.name for d in devices.devices if d.items]
    if name:
        if name not in names:
            raise RemoteProtocolError(f"the agent has no device {name!r} (it has {names})")
        return name
    real = [d.name for d in devices.devices if d.items and not _is_agent(d.items)]
    if len(real) != 1:
        raise RemoteProtocolError(
            f"the agent has {len(real)} devices {real}: name one with `device = ...`"
        )
    return real[0]


def _is_agent(items: tuple[DataItem, ...]) -> bool:
    # MTConnect 2.x agents describe themselves as an Agent device with these items
    return any(i.type == "ADAPTER_URI" or i.type == "AGENT_VERSION" for i in items)


class DeviceState:
    """The latest values of one device's data items."""

    def __init__(self, devices: Devices, device: str) -> None:
        self.device = pick_device(devices, device)
        self.instance_id = devices.header.instance_id
        items = next(d.items for d in devices.devices if d.name == self.device)
        self._field: dict[str, str] = {}  # data item id -> snapshot field
        self._conditions: dict[str, DataItem] = {}
        self._values: dict[str, str] = {}  # snapshot field -> latest text
        # per condition item: active entries by native code ("" for the item's only one)
        self._active: dict[str, dict[str, tuple[str, str]]] = {}
        taken: set[str] = set()
        for item in items:
            if item.category == "CONDITION":
                self._conditions[item.id] = item
                continue
            field = _FIELDS.get(item.type)
            if field is None or field in taken:
                continue  # the first path's item wins (a multi-path lathe: path 1)
            if field == "part_count" and item.sub_type in _NOT_THE_COUNT:
                continue
            if field == "line" and item.sub_type in _NOT_THE_LINE:
                continue
            self._field[item.id] = field
            taken.add(field)
        self.last_sequence = 0  # the newest observation taken
        # Every device of MTConnect 1.1 and later has an Availability item; one without it
        # (an older agent) is taken as available while its agent answers.
        self._has_availability = "availability" in taken

    def load(self, current: Streams) -> None:
        """Take a ``current`` answer: every value as it is now (what was known before goes)."""
        self._check(current)
        self._values.clear()
        self._active.clear()
        for observation in current.observations:
            self._take(observation)
        self.last_sequence = max(current.header.next_sequence - 1, 0)

    def update(self, sample: Streams) -> int:
        """Take a ``sample`` answer's observations newer than the last taken; how many."""
        self._check(sample)
        taken = 0
        for observation in sample.observations:
            if observation.sequence <= self.last_sequence:
                continue  # seen already: a resent observation must not count twice
            self._take(observation)
            taken += 1
        # A sample answer holds every observation of ours up to its nextSequence - 1 (a
        # device's stream skips the other devices' ones, and a quiet one is empty): the next
        # request starts there.
        newest = max((o.sequence for o in sample.observations), default=0)
        self.last_sequence = max(self.last_sequence, newest, sample.header.next_sequence - 1)
        return taken

    def _check(self, streams: Streams) -> None:
        if streams.header.instance_id != self.instance_id:
            raise RemoteProtocolError(
                f"the agent restarted (instance {self.instance_id} is now "
                f"{streams.header.instance_id}): probe again"
            )

    def _take(self, observation: Observation) -> None:
        if observation.device and observation.device != self.device:
            return
        ident = observation.data_item_id
        if observation.condition is not None:
            if ident in self._conditions:
                self._condition(ident, observation)
            return
        field = self._field.get(ident)
        if field is not None:
            self._values[field] = observation.value

    def _condition(self, ident: str, observation: Observation) -> None:
        condition = observation.condition
        assert condition is not None
        # an activation is told apart by its conditionId (2.3+), else by its native code
        level, code = condition.level, condition.condition_id or condition.native_code
        active = self._active.setdefault(ident, {})
        if level in ("Normal", "Unavailable"):
            # Normal with a code clears that entry; without one (or Unavailable), all of them
            if code and level == "Normal":
                active.pop(code, None)
            else:
                active.clear()
            return
        text = observation.value or ""
        described = " ".join(p for p in (condition.native_code, text) if p)
        described = described or self._conditions[ident].type
        active[code] = (level, described)

    def snapshot(self) -> Snapshot:
        """The latest values."""
        values = self._values

        def text(field: str) -> str | None:
            value = values.get(field)
            return None if value is None or value == UNAVAILABLE else value

        def number(field: str) -> int | None:
            # A line, part count or tool number is a whole number from 0 to 2**31 - 1 (what
            # the database's Integer column holds); anything else ("12a", "nan", "1e300",
            # "-5", "2.5") reads as unavailable, not as a value nothing downstream can keep.
            value = text(field)
            if value is None:
                return None
            try:
                number = float(value)
            except ValueError:  # "12a"
                return None
            if not number.is_integer() or not 0 <= number <= MAX_NUMBER:  # also nan, inf
                return None
            return int(number)

        faults: list[str] = []
        warnings: list[str] = []
        for entries in self._active.values():
            for level, description in entries.values():
                (faults if level == "Fault" else warnings).append(description)
        return Snapshot(
            availability=text("availability") if self._has_availability else "AVAILABLE",
            execution=text("execution"),
            controller_mode=text("controller_mode"),
            emergency_stop=text("emergency_stop"),
            program=text("program"),
            line=number("line"),
            part_count=number("part_count"),
            tool=number("tool"),
            message=text("message"),
            faults=tuple(faults),
            warnings=tuple(warnings),
        )
