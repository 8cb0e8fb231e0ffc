"""Blocking serial stream on pyserial, on every platform.

pyserial opens devices (``/dev/ttyUSB0``, ``COM3``, pty slaves) with its platform back end
(termios on POSIX, the Win32 API on Windows) and its own URL handlers (``rfc2217://``,
``loop://``, ``spy://``, ``socket://`` with options). This module imports pyserial only when
a port is opened, so the rest of opendnc (TCP LSV2, ``socket://`` XModem) imports and runs
where pyserial or termios are missing. Commands open ports through
:func:`opendnc.transport.open_stream`, which sends plain TCP addresses elsewhere.
"""

from __future__ import annotations

import errno
import sys
from typing import TYPE_CHECKING

from opendnc.errors import InputError, PeerClosed, TransportError, TransportTimeout
from opendnc.transport.line import Handshake, check_line
from opendnc.transport.marks import LineData, MarkDecoder, enable_marks

if TYPE_CHECKING:
    import serial


def _line_errors() -> tuple[type[BaseException], ...]:
    """termios.error, when pyserial's POSIX back end loaded termios: it is no OSError."""
    termios = sys.modules.get("termios")
    return (termios.error,) if termios is not None else ()


def _reason(exc: BaseException) -> str:
    """Why a port did not open, in one line: pyserial wraps the OS error in its own text."""
    cause = exc.__context__
    if isinstance(cause, OSError) and cause.strerror:
        reason = cause.strerror
    elif cause is not None and len(cause.args) == 2 and isinstance(cause.args[1], str):
        reason = cause.args[1]  # termios.error(errno, text)
    else:
        return str(exc)
    code = getattr(cause, "errno", None) or cause.args[0]
    if code == errno.ENOENT:
        return f"{reason} (is the adapter plugged in?)"
    if code == errno.EACCES:
        return f"{reason} (on Linux: add yourself to the dialout group)"
    if code == errno.ENOTTY:
        return f"{reason} (not a serial port)"
    return reason


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
    write_timeout: float | None = None,
) -> serial.SerialBase:
    """Open ``url`` with pyserial, raising :class:`TransportError` on failure.

    Most code wants :func:`opendnc.transport.open_stream` instead; this returns the raw
    pyserial port for callers that need its modem lines.
    """
    check_line(parity, bytesize, stopbits, "none")
    try:
        import serial
    except ImportError as exc:
        raise TransportError(f"cannot open serial port {url}: pyserial is missing ({exc})") from exc
    try:
        return serial.serial_for_url(
            url,
            baudrate=baudrate,
            parity=parity.upper(),
            bytesize=bytesize,
            stopbits=stopbits,
            rtscts=rtscts,
            xonxoff=xonxoff,
            timeout=timeout,
            write_timeout=write_timeout,
        )
    except (serial.SerialException, OSError) as exc:
        raise TransportError(f"cannot open serial port {url}: {_reason(exc)}") from exc
    except (ValueError, LookupError) as exc:  # pyserial's URL handlers, on a bad option
        detail = f"unknown option value {exc}" if isinstance(exc, KeyError) else str(exc)
        raise InputError(f"bad port {url!r}: {detail}") from exc
    except _line_errors() as exc:
        # a device (a pty, for one) refusing the line settings
        why = exc.args[1] if len(exc.args) > 1 else exc
        raise TransportError(
            f"cannot open serial port {url}: it refuses {baudrate} baud, {bytesize}"
            f"{parity.upper()}{stopbits:g} ({why})"
        ) from exc


class SerialStream:
    """A :class:`~opendnc.transport.base.PortStream` over a pyserial port.

    ``flow`` is the port's own handshake (``"rtscts"``, ``"xonxoff"``; see :data:`Handshake`).
    ``write_timeout`` bounds a write the line holds back (CTS low, XOFF): ``None`` waits
    forever. ``mark_errors`` asks the port to mark characters that failed their parity or
    framing check (:mod:`opendnc.transport.marks`; POSIX devices only): :meth:`read_marked`
    then reports where they are, and :meth:`read` hands them over as NUL.
    """

    def __init__(
        self,
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
    ) -> None:
        check_line(parity, bytesize, stopbits, flow)
        self.url = url
        self.port = open_serial(
            url,
            baudrate,
            parity=parity,
            bytesize=bytesize,
            stopbits=stopbits,
            rtscts=flow == "rtscts",
            xonxoff=flow == "xonxoff",
            timeout=timeout,
            write_timeout=write_timeout,
        )
        import serial  # loaded by open_serial: the exception types of this port

        self._errors = serial.SerialException
        self._write_timeout = serial.SerialTimeoutException
        self._marks: MarkDecoder | None = None
        if mark_errors and enable_marks(self.port):
            self._marks = MarkDecoder()

    @property
    def marks_errors(self) -> bool:
        """True when the port marks characters that failed their parity or framing check."""
        return self._marks is not None

    def read_marked(self, max_bytes: int) -> LineData:
        """Like :meth:`read`, with the positions of characters that arrived with an error.

        On a marking port a call may return no bytes at all (only the start of a mark came);
        on any other port ``errors`` is always empty."""
        raw = self._read_raw(max_bytes)
        return LineData(raw) if self._marks is None else self._marks.decode(raw)

    def read(self, max_bytes: int) -> bytes:
        if self._marks is None:
            return self._read_raw(max_bytes)
        while True:
            got = self._marks.decode(self._read_raw(max_bytes))
            if got.data:
                break
        if not got.errors:
            return got.data
        data = bytearray(got.data)
        for i in got.errors:
            data[i] = 0  # what a port without marking hands over (INPCK alone)
        return bytes(data)

    def _read_raw(self, max_bytes: int) -> bytes:
        try:
            first = self.port.read(1)
            if not first:
                raise TransportTimeout(f"no data on {self.url}")
            waiting = int(getattr(self.port, "in_waiting", 0))
            if waiting and max_bytes > 1:
                first += self.port.read(min(waiting, max_bytes - 1))
        except self._errors as exc:
            # pyserial reports a vanished peer (pty master closed, socket dropped) this way
            raise PeerClosed(f"{self.url}: {exc}") from exc
        except OSError as exc:
            raise _read_error(self.url, exc) from exc
        return bytes(first)

    def read_nowait(self, max_bytes: int) -> bytes:
        try:
            waiting = int(getattr(self.port, "in_waiting", 0))
            if not waiting:
                return b""
            raw = bytes(self.port.read(min(waiting, max_bytes)))
            return raw if self._marks is None else self._marks.decode(raw).data
        except self._errors as exc:
            raise PeerClosed(f"{self.url}: {exc}") from exc
        except OSError as exc:
            raise _read_error(self.url, exc) from exc

    def write(self, data: bytes) -> None:
        try:
            self.port.write(data)
        except self._write_timeout as exc:
            raise TransportTimeout(
                f"write to {self.url} timed out (the line holds our data back: CTS or XOFF)"
            ) from exc
        except (self._errors, OSError) as exc:
            raise TransportError(f"write to {self.url} failed: {exc}") from exc

    def drain(self) -> None:
        try:
            self.port.flush()
        except (self._errors, OSError) as exc:
            raise TransportError(f"write to {self.url} failed: {exc}") from exc

    def set_timeout(self, seconds: float | None) -> None:
        # pyserial re-applies every port setting on a timeout change; skip no-op changes
        if self.port.timeout != seconds:
            self.port.timeout = seconds

    def close(self) -> None:
        self.port.close()


# callers written before the dispatcher had a module of its own import it from here
from opendnc.transport.urls import open_stream  # noqa: E402

__all__ = ["SerialStream", "open_serial", "open_stream"]


def _read_error(url: str, exc: OSError) -> TransportError:
    # EIO on a read is a hang-up: the far end of a pty (or a USB adapter) is gone. Sometimes
    # it arrives as a bare OSError instead of pyserial's exception; it is still the peer
    # leaving, which a sender that already sent its EOT counts as the end of the transfer.
    if exc.errno == errno.EIO:
        return PeerClosed(f"{url}: {exc.strerror or exc}")
    return TransportError(f"read from {url} failed: {exc}")
