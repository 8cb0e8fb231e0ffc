"""The virtual null-modem cable: two ptys joined at a real line rate, with seeded faults.

See :mod:`opendnc.sim.cable.link` for how to use it from Python and
:mod:`opendnc.sim.cable.noise` for the fault model, :mod:`opendnc.sim.cable.monitor` for the
line monitor (a timestamped record of what crossed the cable).
"""

from opendnc.sim.cable.link import CableStats, LaneStats, VirtualCable
from opendnc.sim.cable.monitor import MonitorRecord, read_monitor
from opendnc.sim.cable.noise import LineNoise, NoiseResult
from opendnc.sim.cable.process import CableProcess

__all__ = [
    "CableProcess",
    "CableStats",
    "LaneStats",
    "LineNoise",
    "MonitorRecord",
    "NoiseResult",
    "VirtualCable",
    "read_monitor",
]
