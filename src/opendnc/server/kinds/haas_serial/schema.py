"""The configuration schema of a ``haas_serial`` machine (its own module: the connector reads it,
and the kind's spec imports the connector)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

from opendnc.nccheck.limits import HAAS_PROTECTED
from opendnc.server.kinds.base import MachineBase, SerialProfile

__all__ = ["HaasSerialMachine"]


@dataclass(frozen=True, kw_only=True)
class HaasSerialMachine(MachineBase):
    """A Haas control on a serial line."""

    kind: ClassVar[str] = "haas_serial"
    control_family: ClassVar[str | None] = "haas"
    protected_programs: ClassVar[tuple[tuple[int, int], ...]] = (HAAS_PROTECTED,)

    serial: str  # device or URL (socket://, rfc2217://)
    profile: SerialProfile = field(default_factory=SerialProfile)
    dripfeed: bool = False  # drip-feeding runs the program on the machine: an explicit opt-in
    mdc: bool = False  # status by MDC Q-commands on the port (Setting 143 ON)
    mdc_interval: float = 3.0  # least seconds between two MDC status reads
    dprnt: str = ""  # "serial" (the same port) or tcp://HOST:PORT; "" for none
