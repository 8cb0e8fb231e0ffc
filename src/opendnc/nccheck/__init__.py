"""Pre-flight dry run of NC programs: check a program on a virtual control, without I/O.

::

    from opendnc.nccheck import check_text

    result = check_text(text, name="O03000.nc")
    for problem in result.problems:
        print(problem.format(result.name))
    print(result.summary())

:func:`check_text` runs the whole program: G-code (Haas, Fanuc macro B, Heidenhain ISO)
through the macro interpreter of :mod:`opendnc.gcode`, Heidenhain conversational (Klartext)
through :mod:`opendnc.nccheck.klartext`. It never raises on program text and always ends
(block and time budgets); everything it finds is a :class:`Problem` of the
:class:`CheckResult`, with the tools, moves, extents and an estimated cycle time for a
preview. The facts it relies on are in docs/check.md.
"""

from __future__ import annotations

from opendnc.nccheck.api import Budget, Library, check_file, check_text, guess_control
from opendnc.nccheck.limits import MachineLimits, limits_for, parse_travel, parse_work_offsets
from opendnc.nccheck.result import (
    MAX_PROBLEMS,
    CheckResult,
    Control,
    EndState,
    Move,
    MoveKind,
    Plane,
    Problem,
    Severity,
    Stock,
    ToolUse,
    Units,
)

__all__ = [
    "MAX_PROBLEMS",
    "Budget",
    "CheckResult",
    "Control",
    "EndState",
    "Library",
    "MachineLimits",
    "Move",
    "MoveKind",
    "Plane",
    "Problem",
    "Severity",
    "Stock",
    "ToolUse",
    "Units",
    "check_file",
    "check_text",
    "guess_control",
    "limits_for",
    "parse_travel",
    "parse_work_offsets",
]
