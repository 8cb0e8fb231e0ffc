"""The virtual Haas: control model, MDC server, DPRNT outputs, synthetic probing surfaces."""

from opendnc.sim.haas.app import SimHaas, SimHaasThread, SimOptions
from opendnc.sim.haas.control import (
    ALARM_DNC_LINK,
    DprntDestination,
    DprntOutput,
    HaasConfig,
    HaasControl,
)
from opendnc.sim.haas.surface import HeightMap, SurfaceSpec, parse_surface

__all__ = [
    "ALARM_DNC_LINK",
    "DprntDestination",
    "DprntOutput",
    "HaasConfig",
    "HaasControl",
    "HeightMap",
    "SimHaas",
    "SimHaasThread",
    "SimOptions",
    "SurfaceSpec",
    "parse_surface",
]
