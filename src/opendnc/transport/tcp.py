"""Blocking TCP stream with errors mapped onto the opendnc tree."""

from __future__ import annotations

import select
import socket
import struct
import sys

from opendnc.errors import PeerClosed, TransportError, TransportTimeout, os_reason
from opendnc.transport.spin import DEFAULT_WINDOW, BusyPoll

# Python's socket timeouts poll() before every recv()/send(): one extra syscall and a few
# microseconds per telegram. Where the kernel offers per-socket timeouts (SO_RCVTIMEO /
# SO_SNDTIMEO), the socket stays blocking and the kernel enforces the limit instead; a call
# that runs out of time fails with EAGAIN, which we report as TransportTimeout.
_KERNEL_TIMEOUTS = sys.platform.startswith("linux") and hasattr(socket, "SO_RCVTIMEO")
_TIMEVAL = struct.Struct("@ll")


def _timeval(seconds: float | None) -> bytes:
    if seconds is None:
        return _TIMEVAL.pack(0, 0)  # zero means "no limit" to the kernel
    whole = int(seconds)
    micro = max(1, round((seconds - whole) * 1e6)) if whole == 0 else round((seconds - whole) * 1e6)
    if micro >= 1_000_000:
        whole, micro = whole + 1, micro - 1_000_000
    return _TIMEVAL.pack(whole, micro)


# Busy-polling needs a receive that never waits; Python's own socket timeouts (used where the
# kernel ones are missing) would make MSG_DONTWAIT wait the whole timeout first.
_CAN_SPIN = _KERNEL_TIMEOUTS and hasattr(socket, "MSG_DONTWAIT")
CONNECT_TIMEOUT = 5.0  # seconds at least for the TCP handshake, whatever the read timeout
WRITE_TIMEOUT = 10.0  # seconds a write may wait for the peer to take data (kernel timeouts)


class TcpStream:
    """A connected TCP socket with ``TCP_NODELAY`` set.

    Request/response protocols send small telegrams; without ``TCP_NODELAY`` Nagle's
    algorithm and delayed ACKs cost tens of milliseconds per round trip.

    ``timeout`` limits each read (:meth:`set_timeout` changes it). Connecting may take at
    least :data:`CONNECT_TIMEOUT` and a write up to :data:`WRITE_TIMEOUT` (or ``timeout`` if
    longer), so a short poll interval chosen for reads never cuts a slow handshake or a
    peer holding back a block. Reads busy-poll for up to ``busy_poll`` seconds while answers
    keep coming that fast (see :mod:`opendnc.transport.spin`; 0 turns it off).
    """

    def __init__(
        self,
        host: str,
        port: int,
        timeout: float | None = 10.0,
        *,
        busy_poll: float = DEFAULT_WINDOW,
    ) -> None:
        self.host, self.port = host, port
        self._spin = BusyPoll(busy_poll if _CAN_SPIN else 0.0)
        connect = None if timeout is None else max(timeout, CONNECT_TIMEOUT)
        try:
            self._sock = socket.create_connection((host, port), timeout=connect)
        except TimeoutError as exc:
            raise TransportTimeout(f"connecting to {host}:{port} timed out") from exc
        except OSError as exc:
            raise TransportError(f"cannot connect to {host}:{port}: {os_reason(exc)}") from exc
        except (UnicodeError, ValueError, OverflowError) as exc:  # a malformed host or port
            raise TransportError(f"cannot connect to {host}:{port}: {exc}") from exc
        self._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        if _KERNEL_TIMEOUTS:
            self._sock.settimeout(None)
            write = None if timeout is None else max(timeout, WRITE_TIMEOUT)
            self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDTIMEO, _timeval(write))
        self.set_timeout(timeout)
        self._closed = False

    def read(self, max_bytes: int) -> bytes:
        if not self._spin.enabled:
            return self._recv(max_bytes)
        return self._spin.read(
            lambda: self._receive(max_bytes, socket.MSG_DONTWAIT), lambda: self._recv(max_bytes)
        )

    def read_nowait(self, max_bytes: int) -> bytes:
        """What has already arrived (up to ``max_bytes``), ``b""`` if nothing; never waits."""
        if _CAN_SPIN:
            return self._receive(max_bytes, socket.MSG_DONTWAIT) or b""
        # no MSG_DONTWAIT (Windows): ask select() first, then recv() cannot block
        readable, _, _ = select.select([self._sock], [], [], 0)
        if not readable:
            return b""
        return self._receive(max_bytes, 0) or b""

    def drain(self) -> None:
        """Nothing to wait for: ``write`` returns once the kernel has taken the data."""

    def _recv(self, max_bytes: int) -> bytes:
        data = self._receive(max_bytes, 0)
        if data is None:
            raise TransportTimeout(f"no answer from {self.host}:{self.port}")
        return data

    def _receive(self, max_bytes: int, flags: int) -> bytes | None:
        """One recv: data, or None when nothing came (non-blocking, or the timeout ran out)."""
        try:
            data = self._sock.recv(max_bytes, flags)
        except (TimeoutError, BlockingIOError):
            return None
        except OSError as exc:
            raise self._failed(exc) from exc
        if not data:
            raise PeerClosed(f"{self.host}:{self.port} closed the connection")
        return data

    def _failed(self, exc: OSError) -> TransportError:
        if isinstance(exc, ConnectionResetError):
            return PeerClosed(f"{self.host}:{self.port} reset the connection")
        return TransportError(f"receive from {self.host}:{self.port} failed: {exc}")

    def write(self, data: bytes) -> None:
        try:
            self._sock.sendall(data)
        except (TimeoutError, BlockingIOError) as exc:
            raise TransportTimeout(f"send to {self.host}:{self.port} timed out") from exc
        except OSError as exc:
            raise TransportError(f"send to {self.host}:{self.port} failed: {exc}") from exc

    def set_timeout(self, seconds: float | None) -> None:
        """Limit each later read to ``seconds`` (``None``: wait forever, ``0``: never wait;
        both raise :class:`TransportTimeout` when nothing came)."""
        if not _KERNEL_TIMEOUTS or seconds == 0:
            # Python's timeout covers writes as well; acceptable where the kernel has none
            self._sock.settimeout(seconds)
            return
        self._sock.settimeout(None)
        self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVTIMEO, _timeval(seconds))

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._sock.close()
