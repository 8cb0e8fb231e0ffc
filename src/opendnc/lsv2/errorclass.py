"""Words for the class of an NC error message (``R_RI`` 27/28, docs/lsv2-nc-error-classes.md).

The wire carries the class as a number; people read "program halt", not "3".
"""

from __future__ import annotations

import enum

__all__ = ["NcErrorClass", "class_name"]


class NcErrorClass(enum.IntEnum):
    """What an NC error does to the machine (numbering of HEIDENHAIN's DNC interface)."""

    NONE = 0
    WARNING = 1
    FEED_HOLD = 2
    PROGRAM_HALT = 3
    PROGRAM_ABORT = 4
    EMERGENCY_STOP = 5
    RESET = 6
    INFO = 7
    ERROR = 8
    NOTE = 9


def class_name(value: int) -> str:
    """``3`` -> ``"program halt"``; a number outside the known set -> ``"class 42"``."""
    try:
        return NcErrorClass(value).name.lower().replace("_", " ")
    except ValueError:
        return f"class {value}"
