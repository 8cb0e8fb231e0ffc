"""The configuration schema of a ``haas_ngc`` machine (its own module: the connector reads it,
and the kind's spec imports the connector)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from opendnc.nccheck.limits import HAAS_PROTECTED
from opendnc.server.kinds.base import MachineBase

__all__ = ["HaasNgcMachine"]


@dataclass(frozen=True, kw_only=True)
class HaasNgcMachine(MachineBase):
    """A Haas NGC control on the network."""

    kind: ClassVar[str] = "haas_ngc"
    control_family: ClassVar[str | None] = "haas"
    protected_programs: ClassVar[tuple[tuple[int, int], ...]] = (HAAS_PROTECTED,)

    host: str
    mdc_port: int = 5051
    share: str = ""  # the net share folder programs go to (local path or smb://)
    dprnt: str = ""  # tcp://HOST:PORT where the control prints (Setting 263); "" for none
