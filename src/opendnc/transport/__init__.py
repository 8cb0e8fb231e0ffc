"""Byte streams that protocol engines run over.

Every stream offers ``read(max_bytes)`` (returns at least one byte, raises
:class:`~opendnc.errors.TransportTimeout` when nothing came in time and
:class:`~opendnc.errors.PeerClosed` when the peer is gone), ``write(data)`` and ``close()``.
"""

from opendnc.transport.base import ByteStream
from opendnc.transport.fd import FdStream
from opendnc.transport.serial import SerialStream, open_serial
from opendnc.transport.tcp import TcpStream

__all__ = ["ByteStream", "FdStream", "SerialStream", "TcpStream", "open_serial"]
