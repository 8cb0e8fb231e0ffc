"""The one place that opens ports: a URL or device name in, a byte stream out.

    from opendnc.transport import open_stream

    stream = open_stream("/dev/ttyUSB0", 9600, parity="E", bytesize=7, stopbits=2,
                         flow="rtscts", timeout=0.5, write_timeout=30)
    stream.write(b"%\\n")
    data = stream.read(1024)          # 1..1024 bytes, TransportTimeout after 0.5 s

:func:`open_stream` returns a :class:`~opendnc.transport.base.PortStream` (a
:class:`~opendnc.transport.base.ByteStream` plus ``read_nowait`` and ``drain``) for:

* a serial device: ``/dev/ttyUSB0``, ``/dev/ttyS0``, a pty slave, ``COM3`` (pyserial, on
  every platform);
* ``tcp://HOST:PORT`` and ``socket://HOST:PORT``: a plain TCP connection, such as a serial
  device server in raw TCP mode or a Haas with Setting 263 (our :class:`TcpStream`, which
  reads whatever has arrived in one call; pyserial's socket handler reports one byte waiting
  at most, so a 1K XModem block took hundreds of reads). ``socket://`` with pyserial options
  (``socket://HOST:PORT?logging=debug``) goes to pyserial;
* ``rfc2217://HOST:PORT`` (a device server that also carries the line settings), ``loop://``
  (a loopback for tests), ``spy://``, ``hwgrep://``, ``alt://``, ``cp2110://`` (pyserial).

Line settings (``baudrate``, ``parity`` N/E/O/M/S, ``bytesize`` 5-8, ``stopbits`` 1/1.5/2,
``flow`` none/rtscts/xonxoff) are checked for every URL but apply only where a line exists
(devices, rfc2217): a TCP server port has its own. ``timeout`` limits each read (``None``
waits forever); ``write_timeout`` limits a write the line holds back (CTS low, a kernel
XOFF) and is ``None`` (no limit) by default; TCP streams always bound writes (see
:class:`TcpStream`).

Errors: a malformed address is an :class:`~opendnc.errors.InputError`; a port that does not
open is one :class:`~opendnc.errors.TransportError` with a hint where one helps (``host:port``
without a scheme: "did you mean tcp://host:port?"). Nothing here retries.

The facts behind these choices (device servers, RFC 2217, pyserial's ``socket://``) are in
docs/ports.md.
"""

from __future__ import annotations

import os
import re
from urllib.parse import urlsplit

from opendnc.errors import InputError
from opendnc.transport.base import PortStream
from opendnc.transport.line import Handshake, check_line
from opendnc.transport.tcp import TcpStream

TCP_SCHEMES = ("tcp", "socket")
PYSERIAL_SCHEMES = ("socket", "rfc2217", "loop", "spy", "hwgrep", "alt", "cp2110")
SCHEMES = ("tcp", *PYSERIAL_SCHEMES)

_HOST_PORT = re.compile(r"^(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9][A-Za-z0-9.-]*):\d{1,5}$")


def looks_like_host_port(spec: str) -> bool:
    """True for ``host:port`` written without a scheme (and not a file that exists)."""
    return bool(_HOST_PORT.match(spec)) and not os.path.exists(spec)


def _tcp_address(url: str, scheme: str) -> tuple[str, int]:
    try:
        parts = urlsplit(url)
        host, port = parts.hostname, parts.port
    except ValueError:  # a bad port number or bracket
        host = port = None
    if not host or port is None or parts.path not in ("", "/"):
        raise InputError(f"bad address {url!r}: use {scheme}://HOST:PORT")
    return host, port


def open_stream(
    url: str,
    baudrate: int = 9600,
    *,
    parity: str = "N",
    bytesize: int = 8,
    stopbits: float = 1,
    flow: Handshake = "none",
    timeout: float | None = 1.0,
    write_timeout: float | None = None,
    mark_errors: bool = False,
) -> PortStream:
    """Open ``url`` (a device or one of :data:`SCHEMES`) as a stream; see the module doc.

    ``mark_errors`` makes a POSIX serial device mark characters that failed their parity or
    framing check (:mod:`opendnc.transport.marks`); elsewhere it changes nothing."""
    check_line(parity, bytesize, stopbits, flow)
    scheme, sep, rest = url.partition("://")
    if sep:
        scheme = scheme.lower()
        if scheme not in SCHEMES:
            raise InputError(
                f"unknown port type {scheme}:// in {url!r}: use a device such as /dev/ttyUSB0 "
                "or COM3, tcp://, socket://, rfc2217:// or loop://"
            )
        if scheme in TCP_SCHEMES and "?" not in rest:
            host, port = _tcp_address(url, scheme)
            return TcpStream(host, port, timeout=timeout)
        if scheme == "tcp":
            raise InputError(f"bad address {url!r}: tcp:// takes no options, use tcp://HOST:PORT")
    elif not url.strip():
        raise InputError("no port given: use a device such as /dev/ttyUSB0 or COM3, or tcp://")
    elif looks_like_host_port(url):
        raise InputError(f"no serial port named {url!r} (did you mean tcp://{url}?)")
    from opendnc.transport.serial import SerialStream  # pyserial loads only for these

    return SerialStream(
        url,
        baudrate,
        parity=parity,
        bytesize=bytesize,
        stopbits=stopbits,
        flow=flow,
        timeout=timeout,
        write_timeout=write_timeout,
        mark_errors=mark_errors,
    )
