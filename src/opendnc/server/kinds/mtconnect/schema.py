"""The configuration schema of a ``mtconnect`` machine (its own module: the connector reads it,
and the kind's spec imports the connector)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from opendnc.server.kinds.base import MachineBase

__all__ = ["MtconnectMachine"]


@dataclass(frozen=True, kw_only=True)
class MtconnectMachine(MachineBase):
    """A machine read through an MTConnect agent."""

    kind: ClassVar[str] = "mtconnect"

    url: str  # the agent: http://host:5000 (a path prefix is kept)
    device: str = ""  # the device's name at the agent; "" when the agent has only one
    streaming: bool = True  # sample?interval= stream; False polls current every poll_interval
