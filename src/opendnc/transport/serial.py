"""Blocking serial stream on pyserial, accepting any URL ``serial_for_url`` opens.

Devices (``/dev/ttyUSB0``, ``COM3``), pty slaves, ``socket://host:port``,
``rfc2217://host:port``, ``spy://`` and ``loop://`` all work the same way.
:func:`open_stream` is what commands use: it opens plain ``socket://`` and ``tcp://``
addresses as TCP streams and everything else through pyserial.
"""

from __future__ import annotations

import termios
from typing import Any
from urllib.parse import urlsplit

import serial

from opendnc.errors import InputError, PeerClosed, TransportError, TransportTimeout
from opendnc.transport.base import ByteStream
from opendnc.transport.tcp import TcpStream

PARITIES = {"N": serial.PARITY_NONE, "E": serial.PARITY_EVEN, "O": serial.PARITY_ODD}


def open_serial(
    url: str,
    baudrate: int = 9600,
    *,
    parity: str = "N",
    bytesize: int = 8,
    stopbits: float = 1,
    rtscts: bool = False,
    xonxoff: bool = False,
    timeout: float | None = 1.0,
) -> serial.SerialBase:
    """Open ``url`` with pyserial, raising :class:`TransportError` on failure."""
    try:
        return serial.serial_for_url(
            url,
            baudrate=baudrate,
            parity=PARITIES[parity.upper()],
            bytesize=bytesize,
            stopbits=stopbits,
            rtscts=rtscts,
            xonxoff=xonxoff,
            timeout=timeout,
        )
    except KeyError as exc:
        raise TransportError(f"unknown parity {parity!r}: use N, E or O") from exc
    except (serial.SerialException, ValueError, OSError) as exc:
        raise TransportError(f"cannot open serial port {url}: {exc}") from exc
    except termios.error as exc:
        # termios.error is no OSError: a device (a pty, for one) refusing the line settings
        detail = exc.args[1] if len(exc.args) > 1 else exc
        raise TransportError(
            f"cannot open serial port {url}: it refuses {baudrate} baud, {bytesize}"
            f"{parity.upper()}{stopbits:g} ({detail})"
        ) from exc


class SerialStream:
    """A :class:`~opendnc.transport.base.ByteStream` over a pyserial port."""

    def __init__(self, url: str, baudrate: int = 9600, **settings: Any) -> None:
        self.url = url
        self.port = open_serial(url, baudrate, **settings)

    def read(self, max_bytes: int) -> bytes:
        try:
            first = self.port.read(1)
            if not first:
                raise TransportTimeout(f"no data on {self.url}")
            waiting = int(getattr(self.port, "in_waiting", 0))
            if waiting and max_bytes > 1:
                first += self.port.read(min(waiting, max_bytes - 1))
        except serial.SerialException as exc:
            # pyserial reports a vanished peer (pty master closed, socket dropped) this way
            raise PeerClosed(f"{self.url}: {exc}") from exc
        except OSError as exc:
            raise TransportError(f"read from {self.url} failed: {exc}") from exc
        return bytes(first)

    def write(self, data: bytes) -> None:
        try:
            self.port.write(data)
        except serial.SerialTimeoutException as exc:
            raise TransportTimeout(f"write to {self.url} timed out") from exc
        except (serial.SerialException, OSError) as exc:
            raise TransportError(f"write to {self.url} failed: {exc}") from exc

    def set_timeout(self, seconds: float | None) -> None:
        # pyserial re-applies every port setting on a timeout change; skip no-op changes
        if self.port.timeout != seconds:
            self.port.timeout = seconds

    def close(self) -> None:
        self.port.close()


def open_stream(
    url: str, baudrate: int = 9600, *, timeout: float | None = 1.0, **settings: Any
) -> ByteStream:
    """Open a serial line for a protocol engine: a device, a pyserial URL, or plain TCP.

    ``socket://host:port`` (a network serial server in raw TCP mode) and ``tcp://host:port``
    become a :class:`~opendnc.transport.tcp.TcpStream`: pyserial's socket handler reports at
    most one waiting byte, so a 1K XModem block would take hundreds of reads. A ``socket://``
    URL with pyserial options (``?logging=debug``) still goes to pyserial. Baud rate and
    line settings do not apply to TCP; the server's port has its own.
    """
    scheme, sep, rest = url.partition("://")
    if sep and scheme in ("socket", "tcp"):
        if "?" in rest:
            if scheme == "tcp":
                raise InputError(
                    f"bad address {url!r}: tcp:// takes no options, use tcp://HOST:PORT"
                )
            return SerialStream(url, baudrate, timeout=timeout, **settings)
        try:
            parts = urlsplit(url)
            host, port = parts.hostname, parts.port
        except ValueError:  # a bad port number or bracket
            host = port = None
        if not host or port is None:
            raise InputError(f"bad address {url!r}: use {scheme}://HOST:PORT")
        return TcpStream(host, port, timeout=timeout)
    return SerialStream(url, baudrate, timeout=timeout, **settings)
