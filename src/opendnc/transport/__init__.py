"""Byte streams that protocol engines run over, and the one function that opens them.

Every stream offers ``read(max_bytes)`` (returns at least one byte, raises
:class:`~opendnc.errors.TransportTimeout` when nothing came in time and
:class:`~opendnc.errors.PeerClosed` when the peer is gone), ``write(data)``, ``set_timeout``
and ``close()`` (:class:`ByteStream`). :func:`open_stream` opens any port, a device or a URL
(``tcp://``, ``socket://``, ``rfc2217://``, ``loop://``), and returns a :class:`PortStream`,
which adds ``read_nowait`` and ``drain``; see :mod:`opendnc.transport.urls` for its settings.

Nothing here needs termios, fcntl or pty: pyserial loads its own back end when a serial port
is opened. Only :mod:`opendnc.transport.pty` (the simulators' test bench) is POSIX-only, and
:class:`FdStream` needs ``poll()``.
"""

from opendnc.transport.base import ByteStream, PortStream
from opendnc.transport.fd import FdStream
from opendnc.transport.line import Handshake
from opendnc.transport.serial import SerialStream, open_serial
from opendnc.transport.tcp import TcpStream
from opendnc.transport.urls import open_stream

__all__ = [
    "ByteStream",
    "FdStream",
    "Handshake",
    "PortStream",
    "SerialStream",
    "TcpStream",
    "open_serial",
    "open_stream",
]
