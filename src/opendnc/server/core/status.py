"""The status model every connector fills: what a control said about itself.

The status fields follow MTConnect's CNC data items (availability, execution, controller
mode, program, line, part count, message), so the MTConnect adapter and the MQTT publisher
map them one to one (server/outputs/items.py, docs/server.md#open-outputs). Each connector
puts its control's words into that vocabulary itself; where operators know the control's own
word for the mode (a Haas's ``MEM``), it is kept beside it in ``native_mode``
(docs/server.md#machine-status). The last line a Haas printed with DPRNT is what MTConnect
calls a MESSAGE from the program; it has fields of its own (``dprnt``, ``dprnt_at``) because
``message`` also carries the server's own word about the link, which must not overwrite it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime
from typing import Any

__all__ = ["DripProgress", "MachineStatus", "Progress"]

Progress = Callable[[int, int | None], None]
"""Called with (bytes done, bytes total or None) while a transfer runs."""

DripProgress = Callable[[int, int, int, int], None]
"""Called with (program line reached, program lines, program bytes fed from the start line,
program bytes from the start line to the end) while a drip-feed runs: the job's progress, and
what it records if the feed breaks."""


@dataclass(frozen=True)
class MachineStatus:
    """What a control said about itself at ``at``."""

    at: datetime
    available: bool
    execution: str = "UNAVAILABLE"  # ACTIVE, READY, INTERRUPTED, STOPPED, ... (MTConnect)
    mode: str = ""  # AUTOMATIC, MANUAL, MANUAL_DATA_INPUT, SEMI_AUTOMATIC, EDIT (MTConnect)
    native_mode: str = ""  # the control's own word for its mode (a Haas's MEM, MDI, ...)
    program: str = ""
    line: int = 0
    part_count: int | None = None
    tool: int | None = None
    overrides: dict[str, float] = field(default_factory=dict)  # percent
    errors: tuple[str, ...] = ()
    message: str = ""  # the last thing worth telling (a refusal, a lost link)
    dprnt: str = ""  # the last line the program printed with DPRNT (MTConnect MESSAGE)
    dprnt_at: datetime | None = None  # when the server captured it

    def as_json(self) -> dict[str, Any]:
        """A JSON-ready dict."""
        # Field by field, not dataclasses.asdict: this runs for every machine on every poll
        # and every API read, and asdict deep-copies each value through copy's machinery.
        return {
            "at": self.at.isoformat(),
            "available": self.available,
            "execution": self.execution,
            "mode": self.mode,
            "native_mode": self.native_mode,
            "program": self.program,
            "line": self.line,
            "part_count": self.part_count,
            "tool": self.tool,
            "overrides": dict(self.overrides),
            "errors": list(self.errors),
            "message": self.message,
            "dprnt": self.dprnt,
            "dprnt_at": self.dprnt_at.isoformat() if self.dprnt_at else None,
        }
