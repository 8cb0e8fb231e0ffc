"""The virtual Fanuc: a tape-reading control on a serial port (READ, PUNCH, TAPE, DPRNT).

See :mod:`opendnc.sim.fanuc.control`; its parameters and alarms are in
:mod:`opendnc.sim.fanuc.params`.
"""

from opendnc.sim.fanuc.control import FanucOptions, Mode, Selection, VirtualFanuc, parse_mode
from opendnc.sim.fanuc.params import Alarm, FanucParams

__all__ = [
    "Alarm",
    "FanucOptions",
    "FanucParams",
    "Mode",
    "Selection",
    "VirtualFanuc",
    "parse_mode",
]
