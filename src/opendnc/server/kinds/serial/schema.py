"""The configuration schema of a ``serial`` machine (its own module: the connector reads it,
and the kind's spec imports the connector)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from opendnc.server.kinds.base import MachineBase
from opendnc.tape.profiles import Profile

__all__ = ["SerialMachine"]


@dataclass(frozen=True, kw_only=True)
class SerialMachine(MachineBase):
    """A tape-code control on a serial line."""

    kind: ClassVar[str] = "serial"

    serial: str  # device or URL (socket://, rfc2217://), as for a serial Haas
    tape: Profile  # the named profile with this machine's overrides
    dripfeed: bool = False  # drip-feeding runs the program on the machine: an explicit opt-in
    verify: str = ""  # "punch": after a load, wait for the operator's punch back and compare
    verify_timeout: float = 120.0  # seconds the punch back may take to start
