"""The Haas macro variable table: which numbers exist, which a program or MDC may write, and
which values they hold. One model, used by the virtual control (what it stores or refuses)
and by the clients (what they refuse locally before anything goes on the wire).

The facts and their sources are in ``docs/haas-macros.md``. In short:

* ranges that exist are listed in :data:`TABLE`; any other number is refused ("no variable");
* read-only spans (inputs, timers the control keeps, modal information, positions, the tool
  offset in effect, settings and parameters) refuse writes with their meaning as the reason;
* counters hold whole numbers in a range (``#3901``/``#3902`` the M30 counters: 0 to
  :data:`COUNTER_MAX`), so ``-1``, ``-7.5`` or 20 digits are refused, never rounded or stored;
* ``#3000`` is the programmable alarm: assigning ``n`` (1 to 999) stops the program with alarm
  ``1000 + n``, the comment of the block as its text; nothing is stored.

The table uses the numbers of the Haas Next Generation Control; the legacy ones that still
mean the same (``#100``-``#999`` globals, ``#1000``-``#1063`` inputs, ...) are listed too.
"""

from __future__ import annotations

import bisect
import enum
import math
from dataclasses import dataclass

from opendnc.errors import InputError

COUNTER_MAX = 2**31 - 1
"""Largest value of a counter variable (the manual gives no bound; a 32-bit count is ours)."""
ALARM_BASE = 1000
"""``#3000 = n`` raises alarm ``ALARM_BASE + n``."""
ALARM_VARIABLE = 3000


class Access(enum.Enum):
    """What a write to a variable does."""

    READ_WRITE = "read-write"
    READ_ONLY = "read-only"
    ALARM = "alarm"
    """Writing raises the programmable alarm instead of storing (``#3000``)."""


@dataclass(frozen=True, slots=True)
class Span:
    """Variables ``first``..``last`` (inclusive) that share a meaning and rules."""

    first: int
    last: int
    meaning: str
    access: Access = Access.READ_WRITE
    integer: bool = False
    """Holds whole numbers only (a fraction is refused, not truncated)."""
    minimum: float | None = None
    maximum: float | None = None

    def __contains__(self, number: object) -> bool:
        return isinstance(number, int) and self.first <= number <= self.last

    @property
    def label(self) -> str:
        """``#3901`` or ``#1000-#1063``."""
        return f"#{self.first}" if self.first == self.last else f"#{self.first}-#{self.last}"


RW, RO = Access.READ_WRITE, Access.READ_ONLY


def _offsets(first_base: int, count: int, step: int, name: str, first_code: int) -> list[Span]:
    """Work offset blocks: six axes (X Y Z A B C) per offset, ``step`` apart."""
    return [
        Span(first_base + step * k, first_base + step * k + 5, f"{name}{first_code + k} offsets")
        for k in range(count)
    ]


def _counter(first: int, last: int, meaning: str) -> Span:
    return Span(first, last, meaning, RW, integer=True, minimum=0, maximum=COUNTER_MAX)


TABLE: tuple[Span, ...] = tuple(
    sorted(
        [
            Span(0, 0, "the null value", RO),
            Span(1, 33, "macro call arguments (local)"),
            Span(100, 149, "general-purpose globals (legacy numbers)"),
            Span(150, 199, "probe values (legacy numbers)"),
            Span(500, 549, "general-purpose globals (legacy numbers)"),
            Span(550, 599, "probe calibration data (legacy numbers)"),
            Span(600, 699, "general-purpose globals (legacy numbers)"),
            Span(700, 749, "variables reserved for the control (#709: fixture clamp input)"),
            Span(800, 999, "general-purpose globals (legacy numbers)"),
            Span(1000, 1063, "discrete inputs", RO),
            Span(1064, 1068, "maximum axis loads X, Y, Z, A, B"),
            Span(1080, 1087, "raw analog inputs", RO),
            Span(1090, 1098, "filtered analog inputs (#1098: spindle load)", RO),
            Span(1100, 1155, "discrete outputs (legacy numbers)"),
            Span(1264, 1268, "maximum axis loads C, U, V, W, T"),
            _counter(1601, 1800, "number of flutes of tools 1-200"),
            Span(1801, 2000, "maximum recorded vibrations of tools 1-200"),
            Span(2001, 2200, "tool length offsets (geometry)"),
            Span(2201, 2400, "tool length wear"),
            Span(2401, 2600, "tool diameter/radius offsets (geometry)"),
            Span(2601, 2800, "tool diameter/radius wear"),
            Span(
                3000, 3000, "programmable alarm", Access.ALARM, integer=True, minimum=1, maximum=999
            ),
            Span(3001, 3001, "millisecond timer (kept by the control)", RO),
            Span(3002, 3002, "hour timer"),
            Span(3003, 3004, "single-block suppression, feed-hold override"),
            Span(3006, 3006, "programmable stop with message"),
            Span(3011, 3012, "date and time of day", RO),
            Span(3020, 3020, "power-on timer", RO),
            Span(3021, 3022, "cycle-start timer, feed timer"),
            Span(3023, 3025, "present, last and previous part timers", RO),
            Span(3026, 3026, "tool in the spindle", RO),
            Span(3027, 3027, "spindle speed", RO),
            Span(3028, 3028, "pallets loaded on the receiver", RO),
            Span(3030, 3033, "single block, dry run, block delete, optional stop switches"),
            Span(3201, 3400, "actual diameter of tools 1-200"),
            Span(3401, 3600, "programmable coolant positions of tools 1-200"),
            _counter(3901, 3901, "M30 counter 1"),
            _counter(3902, 3902, "M30 counter 2"),
            Span(4001, 4021, "modal information: group codes of the previous block", RO),
            Span(4101, 4126, "modal information: address codes of the previous block", RO),
            Span(5001, 5006, "end position of the previous block", RO),
            Span(5021, 5026, "present machine position", RO),
            Span(5041, 5046, "present work position", RO),
            Span(5061, 5069, "skip signal (probe trigger) position", RO),
            Span(5081, 5086, "tool length offset in effect", RO),
            Span(5201, 5206, "G52 work offsets"),
            *_offsets(5221, 6, 20, "G", 54),
            Span(5401, 5500, "tool feed timers (seconds)"),
            Span(5501, 5600, "total tool timers (seconds)"),
            Span(5601, 5699, "tool life monitor limits"),
            _counter(5701, 5800, "tool life monitor counters"),
            Span(5801, 5900, "tool load monitor: maximum load sensed"),
            Span(5901, 6000, "tool load monitor limits"),
            Span(6001, 6999, "reserved for the control", RO),
            *_offsets(7001, 20, 20, "G", 110),
            Span(7501, 7506, "pallet priority"),
            Span(7601, 7606, "pallet status"),
            Span(7701, 7706, "part program numbers assigned to pallets"),
            _counter(7801, 7806, "pallet usage counts"),
            Span(8500, 8500, "advanced tool management: group to report"),
            Span(8501, 8515, "advanced tool management: group and next-tool figures", RO),
            Span(8550, 8550, "individual tool to report"),
            Span(8551, 8564, "figures of the tool selected by #8550", RO),
            Span(9000, 9019, "thermal compensation accumulators", RO),
            Span(10000, 10149, "general-purpose globals"),
            Span(10150, 10199, "probe values"),
            Span(10200, 10549, "general-purpose globals"),
            Span(10550, 10599, "probe calibration data"),
            Span(10600, 10999, "general-purpose globals"),
            Span(11000, 11255, "discrete inputs", RO),
            Span(12000, 12255, "discrete outputs"),
            *_offsets(14001, 99, 20, "G154 P", 1),
            Span(20000, 29999, "settings (#20000 + setting number)", RO),
            Span(30000, 39999, "parameters (#30000 + parameter number)", RO),
            Span(50001, 52800, "tool table data (type, material, estimates, probing)"),
        ],
        key=lambda span: span.first,
    )
)
"""Every variable span, sorted by first number (see ``docs/haas-macros.md``)."""

_FIRSTS = [span.first for span in TABLE]


def lookup(number: int) -> Span | None:
    """The span holding ``#number``, or ``None`` when the control has no such variable."""
    index = bisect.bisect_right(_FIRSTS, number) - 1
    if index >= 0 and number in TABLE[index]:
        return TABLE[index]
    return None


def exists(number: int) -> bool:
    """True when ``#number`` is a variable of the control."""
    return lookup(number) is not None


def _show(value: float) -> str:
    return f"{value:.0f}" if value == int(value) and abs(value) < 1e16 else f"{value:g}"


def check_value(number: int, span: Span, value: float) -> float:
    """``value`` as ``#number`` (in ``span``) holds it, or :class:`InputError` saying why not."""
    if not math.isfinite(value):
        raise InputError(f"#{number} ({span.meaning}) cannot hold {value!r}")
    if span.integer and value != int(value):
        raise InputError(f"#{number} ({span.meaning}) holds whole numbers only, not {value:g}")
    low, high = span.minimum, span.maximum
    if (low is not None and value < low) or (high is not None and value > high):
        bounds = f"{_show(low or 0)} to {_show(high or 0)}"
        raise InputError(f"#{number} ({span.meaning}) holds {bounds}, not {_show(value)}")
    return float(int(value)) if span.integer else value


def check_write(number: int, value: float | None) -> float | None:
    """What ``#number = value`` stores, or :class:`InputError` with the control's reason.

    ``None`` (the null value) clears a writable variable; it is not a valid alarm number or
    counter value. Writing ``#3000`` is refused here too: it does not store anything, it
    raises an alarm (see :func:`alarm_for`), which only a running program does.
    """
    span = lookup(number)
    if span is None:
        raise InputError(f"#{number} is not a macro variable of the control")
    if span.access is Access.READ_ONLY:
        raise InputError(f"#{number} is read-only ({span.meaning})")
    if span.access is Access.ALARM:
        raise InputError(
            f"#{number} is the programmable alarm: writing it stops the machine with alarm "
            f"{ALARM_BASE}+n, it stores nothing"
        )
    if value is None:
        if span.integer:
            raise InputError(f"#{number} ({span.meaning}) cannot be cleared to null")
        return None
    return check_value(number, span, value)


def alarm_for(value: float | None) -> int:
    """The alarm number ``#3000 = value`` raises, or :class:`InputError` for a bad value."""
    span = lookup(ALARM_VARIABLE)
    assert span is not None  # in TABLE
    if value is None:
        raise InputError(f"#{ALARM_VARIABLE} needs an alarm number 1 to 999, not null")
    return ALARM_BASE + int(check_value(ALARM_VARIABLE, span, value))
