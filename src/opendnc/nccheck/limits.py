"""What a machine allows: control family, travel, work offsets, tools, protected programs.

:class:`MachineLimits` is what :func:`opendnc.nccheck.check_text` checks a program against.
:func:`parse_travel` and :func:`parse_work_offsets` read the optional machine keys of the
server's configuration (``travel = { x = [-30.0, 0.0], ... }``, docs/check.md#machine-limits);
:func:`limits_for` builds the limits of a configured machine. No server imports: the server
imports this module.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol

from opendnc.errors import InputError
from opendnc.nccheck.result import Control, Units

__all__ = [
    "HAAS_PROTECTED",
    "Envelope",
    "LimitsError",
    "MachineLimits",
    "limits_for",
    "parse_envelope",
    "parse_travel",
    "parse_work_offsets",
]

HAAS_PROTECTED = (8000, 9999)
"""Haas program numbers O08000-O09999 hold the control's own macros (probing, tool changer):
a program sent there may overwrite them (docs/check.md#machine-limits)."""

AXES = ("X", "Y", "Z", "A", "B", "C")


class LimitsError(InputError):
    """A travel or work offset table of the configuration is malformed; names the key."""

    def __init__(self, key: str, problem: str) -> None:
        self.key = key
        self.problem = problem
        super().__init__(f"{key}: {problem}")


@dataclass(frozen=True)
class MachineLimits:
    """The machine a program is meant for, as far as the checker knows it."""

    name: str = ""
    family: str | None = None
    """``haas`` or ``heidenhain``: which program languages the control runs (None: any)."""
    travel: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    """Axis (``"X"``) -> (min, max) in machine coordinates."""
    travel_units: Units | None = None
    """Units of :attr:`travel` and :attr:`work_offsets` (None: the program's)."""
    work_offsets: Mapping[str, Mapping[str, float]] = field(default_factory=dict)
    """``"G54"`` (or ``"G154 P3"``, ``"G110"``) -> axis -> offset in machine coordinates."""
    tools: frozenset[str] | None = None
    """Tools the control has (numbers as text, or Heidenhain names); None: not known."""
    protected: tuple[tuple[int, int], ...] = ()
    """Program numbers (inclusive ranges) a program must not be stored as."""
    rapid_rate: float | None = None
    """Rapid traverse in program units per minute, for the time estimate (None: a default)."""
    dialect: str | None = None
    """The G-code control (``haas-lathe``, ``fanuc-mill``, ... of
    :data:`opendnc.nccheck.dialects.DIALECTS`); None: guessed from the program."""

    def accepts(self, control: Control) -> bool:
        """True when this machine's control runs programs written for ``control``."""
        return self.family is None or control.family == self.family


def _pair(value: Any, key: str) -> tuple[float, float]:
    if (
        not isinstance(value, list | tuple)
        or len(value) != 2
        or any(isinstance(v, bool) or not isinstance(v, int | float) for v in value)
    ):
        raise LimitsError(key, f"expected [min, max] in machine coordinates, got {value!r}")
    low, high = float(value[0]), float(value[1])
    if not (math.isfinite(low) and math.isfinite(high)) or low > high:
        raise LimitsError(key, f"expected min <= max, got [{low:g}, {high:g}]")
    return low, high


def _units(value: Any, key: str) -> Units:
    try:
        return Units(str(value).lower())
    except ValueError:
        raise LimitsError(key, 'expected "mm" or "inch"') from None


def parse_travel(raw: Any, key: str) -> tuple[dict[str, tuple[float, float]], Units | None]:
    """``{ x = [-30.0, 0.0], ..., units = "inch" }`` -> (axis ranges, units or None)."""
    if not isinstance(raw, Mapping):
        raise LimitsError(key, "expected a table like { x = [-30.0, 0.0], y = [-16.0, 0.0] }")
    travel: dict[str, tuple[float, float]] = {}
    units: Units | None = None
    for name, value in raw.items():
        if name == "units":
            units = _units(value, f"{key}.units")
            continue
        axis = str(name).upper()
        if axis not in AXES:
            raise LimitsError(f"{key}.{name}", f"unknown axis (expected {', '.join(AXES)})")
        travel[axis] = _pair(value, f"{key}.{name}")
    if not travel:
        raise LimitsError(key, "names no axis")
    return travel, units


_OFFSET_NAME = re.compile(r"^G(5[4-9]|1[12]\d|154 ?P(\d{1,2}))$")


def parse_work_offsets(raw: Any, key: str) -> dict[str, dict[str, float]]:
    """``{ G54 = { x = -15.0, y = -8.0, z = -12.0 } }`` -> offset name -> axis -> value."""
    if not isinstance(raw, Mapping):
        raise LimitsError(key, "expected a table like { G54 = { x = -15.0, z = -12.0 } }")
    out: dict[str, dict[str, float]] = {}
    for name, axes in raw.items():
        code = str(name).upper().replace(" ", "")
        match = _OFFSET_NAME.match(code.replace("P", " P") if "154" in code else code)
        if match is None:
            raise LimitsError(f"{key}.{name}", "expected G54..G59, G110..G129 or G154P1..P99")
        if not isinstance(axes, Mapping):
            raise LimitsError(f"{key}.{name}", "expected a table of axis = offset")
        values: dict[str, float] = {}
        for axis_name, value in axes.items():
            axis = str(axis_name).upper()
            if axis not in AXES:
                raise LimitsError(f"{key}.{name}.{axis_name}", "unknown axis")
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise LimitsError(f"{key}.{name}.{axis_name}", f"expected a number, got {value!r}")
            values[axis] = float(value)
        out[offset_key(code)] = values
    return out


def offset_key(code: str) -> str:
    """Normalised work offset name: ``G54``, ``G110`` or ``G154 P3`` (= ``G112``)."""
    code = code.upper().replace(" ", "")
    if code.startswith("G154P"):
        number = int(code[5:])
        return f"G{109 + number}" if 1 <= number <= 20 else f"G154 P{number}"
    return code


@dataclass(frozen=True)
class Envelope:
    """The optional machine keys of a configured machine for program checks: ``travel``,
    ``work_offsets``, ``rapid_rate`` and ``control`` (docs/check.md#machine-limits)."""

    travel: tuple[tuple[str, float, float], ...] = ()
    """(axis, min, max) in machine coordinates."""
    units: Units | None = None
    work_offsets: tuple[tuple[str, tuple[tuple[str, float], ...]], ...] = ()
    """(offset name, ((axis, value), ...))."""
    rapid_rate: float | None = None
    """Rapid traverse in :attr:`units` (or the program's) per minute, for the time estimate."""
    control: str | None = None
    """The G-code dialect of the machine's control (``haas-lathe``); None: guessed."""

    def travel_map(self) -> dict[str, tuple[float, float]]:
        """Axis -> (min, max)."""
        return {axis: (low, high) for axis, low, high in self.travel}

    def offsets_map(self) -> dict[str, dict[str, float]]:
        """Offset name -> axis -> value."""
        return {name: dict(axes) for name, axes in self.work_offsets}


def parse_envelope(raw: Mapping[str, Any], prefix: str) -> Envelope | None:
    """The ``travel`` / ``work_offsets`` keys of machine table ``raw`` (None when absent).

    :class:`LimitsError` names the bad key (``machines[0].travel.x``).
    """
    if not any(key in raw for key in ("travel", "work_offsets", "rapid_rate", "control")):
        return None
    travel: dict[str, tuple[float, float]] = {}
    units = None
    if "travel" in raw:
        travel, units = parse_travel(raw["travel"], f"{prefix}.travel")
    offsets = (
        parse_work_offsets(raw["work_offsets"], f"{prefix}.work_offsets")
        if "work_offsets" in raw
        else {}
    )
    rapid = raw.get("rapid_rate")
    if rapid is not None and (
        isinstance(rapid, bool)
        or not isinstance(rapid, int | float)
        or not (math.isfinite(rapid) and rapid > 0)
    ):
        raise LimitsError(f"{prefix}.rapid_rate", f"expected units per minute > 0, got {rapid!r}")
    control = raw.get("control")
    if control is not None:
        from opendnc.nccheck.dialects import DIALECTS, dialect_named

        try:
            control = dialect_named(str(control)).name
        except InputError:
            raise LimitsError(
                f"{prefix}.control", f"expected one of {', '.join(DIALECTS)}"
            ) from None
    return Envelope(
        travel=tuple((axis, low, high) for axis, (low, high) in travel.items()),
        units=units,
        work_offsets=tuple((name, tuple(axes.items())) for name, axes in offsets.items()),
        rapid_rate=float(rapid) if rapid is not None else None,
        control=control,
    )


class _MachineLike(Protocol):
    @property
    def name(self) -> str: ...

    @property
    def control_family(self) -> str | None: ...

    @property
    def protected_programs(self) -> tuple[tuple[int, int], ...]: ...


def limits_for(machine: _MachineLike, *, tools: Iterable[str] | None = None) -> MachineLimits:
    """The limits of a configured machine (``server.config.MachineConfig`` or alike).

    The machine's kind says its ``control_family`` (``heidenhain``, ``haas``, or None) and
    its ``protected_programs`` as data, so this module needs nothing of the server; the
    optional ``envelope`` attribute (:class:`Envelope`) gives the travel and work offsets;
    ``tools`` is the tool list the control reported (LSV2 tool table, Haas tool offsets), if
    any. A machine of no family whose ``control`` names a G-code dialect (a tape-code Fanuc)
    runs G-code: the ``haas`` family, as a G-code program's language is called.
    """
    family = machine.control_family
    envelope = getattr(machine, "envelope", None)
    if not isinstance(envelope, Envelope):
        envelope = Envelope()
    if family is None and envelope.control is not None:
        family = "haas"
    return MachineLimits(
        name=machine.name,
        family=family,
        travel=envelope.travel_map(),
        travel_units=envelope.units,
        work_offsets=envelope.offsets_map(),
        tools=frozenset(tools) if tools is not None else None,
        protected=tuple(machine.protected_programs),
        rapid_rate=envelope.rapid_rate,
        dialect=envelope.control,
    )
