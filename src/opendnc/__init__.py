"""opendnc: an open DNC toolkit for CNC machine tools.

Packages, one per protocol family, with sans-IO cores and thin I/O drivers:

- :mod:`opendnc.lsv2` -- Heidenhain LSV2 (client, codec, operations)
- :mod:`opendnc.xmodem` -- XModem as serial CNC controls speak it
- :mod:`opendnc.haas` -- Haas DPRNT, machine-data (MDC) Q-commands, drip-feed, net share
- :mod:`opendnc.transport` -- byte streams over TCP, serial ports (pyserial URLs) and ptys
- :mod:`opendnc.sim` -- virtual controls (TNC, Haas) and the virtual null-modem cable
"""

from opendnc.errors import DncError

__version__ = "0.1.0"
__all__ = ["DncError", "__version__"]
