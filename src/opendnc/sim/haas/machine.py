"""The state a Haas program changes: macro variables, settings, counters, position, tool.

Plain data (no I/O, no clock). Which variables exist and which writes the control accepts
come from the one table in :mod:`opendnc.haas.macros` (``docs/haas-macros.md``): system
variables that mirror state (positions, tool, M30 counters, settings as ``#20000 + n``) are
computed on read; work offsets and globals are stored.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

from opendnc.errors import InputError
from opendnc.haas import macros

AXES = "XYZAB"

# Work offset bases: G54..G59 at #5221 + 20 * k, G52 at #5201; G154 P1..P20 at #7001 + 20 * k.
G52_BASE = 5201


def work_offset_base(code: float) -> int:
    """First variable (X) of work offset ``code``: 52, 54..59, or 110..129 (= G154 P1..P20)."""
    if code == 52:
        return G52_BASE
    if 54 <= code <= 59 and code == int(code):
        return 5221 + 20 * (int(code) - 54)
    if 110 <= code <= 129 and code == int(code):
        return 7001 + 20 * (int(code) - 110)
    raise InputError(f"no work offset G{code:g}")


class Status(enum.Enum):
    """Run state as Q500 reports it."""

    IDLE = "IDLE"
    BUSY = "BUSY"
    FEED_HOLD = "FEED HOLD"
    ALARM = "ALARM ON"


class Mode(enum.Enum):
    """Operating mode as Q104 reports it (NGC words; classic adds parentheses)."""

    MDI = "MDI"
    MEM = "MEM"
    DNC = "DNC"
    ZERO = "ZERO"
    JOG = "JOG"
    EDIT = "EDIT"
    LIST_PROG = "LIST PROG"

    def classic(self) -> str:
        """Classic-control spelling (``ZERO RET`` instead of ``ZERO``)."""
        return "ZERO RET" if self is Mode.ZERO else self.value


@dataclass(frozen=True, slots=True)
class Alarm:
    """An alarm as the control shows it: number and text."""

    code: int
    text: str


@dataclass
class MachineState:
    """Everything a program run reads or writes, owned by the control model."""

    variables: dict[int, float] = field(default_factory=dict)
    settings: dict[int, float | str] = field(default_factory=dict)
    machine_position: list[float] = field(default_factory=lambda: [0.0] * 5)
    previous_end: list[float] = field(default_factory=lambda: [0.0] * 3)
    skip_position: list[float] = field(default_factory=lambda: [0.0] * 3)
    work_offset: float = 54.0
    absolute: bool = True
    tool: int = 0
    next_tool: int = 0
    tool_changes: int = 0
    spindle_rpm: float = 0.0
    m30_counter_1: int = 0
    m30_counter_2: int = 0
    mode: Mode = Mode.MDI
    status: Status = Status.IDLE
    program: str = "MDI"
    alarms: list[Alarm] = field(default_factory=list)
    millis: float = 0.0

    # --------------------------------------------------------------- positions
    def offset(self, axis: int) -> float:
        """Active work offset (plus G52) for ``axis`` (0 = X)."""
        base = work_offset_base(self.work_offset)
        return self.variables.get(base + axis, 0.0) + self.variables.get(G52_BASE + axis, 0.0)

    def work_position(self, axis: int) -> float:
        """Work-coordinate position of ``axis``."""
        return self.machine_position[axis] - self.offset(axis)

    # --------------------------------------------------------------- variables
    def get(self, number: int) -> float | None:
        """Read ``#number``; ``None`` is the null value (``#0`` or never written)."""
        if number == 0:
            return None
        if 5021 <= number <= 5025:
            return self.machine_position[number - 5021]
        if 5041 <= number <= 5045:
            return self.work_position(number - 5041)
        if 5001 <= number <= 5003:
            return self.previous_end[number - 5001]
        if 5061 <= number <= 5063:
            return self.skip_position[number - 5061]
        if number == 3001:
            return self.millis
        if number == 3026:
            return float(self.tool)
        if number == 3027:
            return self.spindle_rpm
        if number == 3901:
            return float(self.m30_counter_1)
        if number == 3902:
            return float(self.m30_counter_2)
        if 20000 < number < 30000:
            setting = self.settings.get(number - 20000)
            return float(setting) if isinstance(setting, int | float) else None
        return self.variables.get(number)

    def set(self, number: int, value: float | None) -> None:
        """Write ``#number`` (``None`` clears it).

        :class:`InputError` with the control's reason for what it refuses
        (:func:`opendnc.haas.macros.check_write`): no such variable, read-only, a value
        outside the variable's range, a fraction in a counter, the ``#3000`` alarm.
        """
        stored = macros.check_write(number, value)
        if number == 3901:
            self.m30_counter_1 = int(stored or 0)
        elif number == 3902:
            self.m30_counter_2 = int(stored or 0)
        elif stored is None:
            self.variables.pop(number, None)
        else:
            self.variables[number] = stored
