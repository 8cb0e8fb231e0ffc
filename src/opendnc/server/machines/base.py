"""The connector interface and the status model every connector fills.

The status fields follow MTConnect's CNC data items (availability, execution, controller
mode, program, line, part count, message), so an MTConnect adapter or an MQTT publisher can
map them one to one later.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from datetime import datetime
from typing import Any, Protocol

__all__ = ["Connector", "MachineStatus", "Progress"]

Progress = Callable[[int, int | None], None]
"""Called with (bytes done, bytes total or None) while a transfer runs."""


@dataclass(frozen=True)
class MachineStatus:
    """What a control said about itself at ``at``."""

    at: datetime
    available: bool
    execution: str = "UNAVAILABLE"  # ACTIVE, READY, INTERRUPTED, STOPPED, ... (MTConnect)
    mode: str = ""  # AUTOMATIC, MANUAL, MANUAL_DATA_INPUT, ... (MTConnect)
    program: str = ""
    line: int = 0
    part_count: int | None = None
    tool: int | None = None
    overrides: dict[str, float] = field(default_factory=dict)  # percent
    errors: tuple[str, ...] = ()
    message: str = ""  # the last thing worth telling (a refusal, a DPRNT line)

    def as_json(self) -> dict[str, Any]:
        """A JSON-ready dict."""
        data = asdict(self)
        data["at"] = self.at.isoformat()
        data["errors"] = list(self.errors)
        return data


class Connector(Protocol):
    """What the supervisor needs from a control."""

    async def connect(self) -> None:
        """Open the link (raise a :class:`~opendnc.errors.DncError` if the control is away)."""

    async def close(self) -> None:
        """Close the link; safe to call at any time."""

    async def status(self) -> MachineStatus:
        """Read the control's state now."""

    async def send(self, name: str, data: bytes, progress: Progress) -> None:
        """Load program ``name`` into the control."""

    async def verify(self, name: str, data: bytes) -> bool | None:
        """Whether the control now holds exactly ``data`` as ``name``; None if it cannot tell."""
