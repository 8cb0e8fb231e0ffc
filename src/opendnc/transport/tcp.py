"""Blocking TCP stream with errors mapped onto the opendnc tree."""

from __future__ import annotations

import socket

from opendnc.errors import PeerClosed, TransportError, TransportTimeout


class TcpStream:
    """A connected TCP socket with ``TCP_NODELAY`` set.

    Request/response protocols send small telegrams; without ``TCP_NODELAY`` Nagle's
    algorithm and delayed ACKs cost tens of milliseconds per round trip.
    """

    def __init__(self, host: str, port: int, timeout: float | None = 10.0) -> None:
        self.host, self.port = host, port
        try:
            self._sock = socket.create_connection((host, port), timeout=timeout)
        except TimeoutError as exc:
            raise TransportTimeout(f"connecting to {host}:{port} timed out") from exc
        except OSError as exc:
            raise TransportError(f"cannot connect to {host}:{port}: {exc.strerror or exc}") from exc
        self._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._sock.settimeout(timeout)
        self._closed = False

    def read(self, max_bytes: int) -> bytes:
        try:
            data = self._sock.recv(max_bytes)
        except TimeoutError as exc:
            raise TransportTimeout(f"no answer from {self.host}:{self.port}") from exc
        except OSError as exc:
            raise TransportError(f"receive from {self.host}:{self.port} failed: {exc}") from exc
        if not data:
            raise PeerClosed(f"{self.host}:{self.port} closed the connection")
        return data

    def write(self, data: bytes) -> None:
        try:
            self._sock.sendall(data)
        except TimeoutError as exc:
            raise TransportTimeout(f"send to {self.host}:{self.port} timed out") from exc
        except OSError as exc:
            raise TransportError(f"send to {self.host}:{self.port} failed: {exc}") from exc

    def set_timeout(self, seconds: float | None) -> None:
        self._sock.settimeout(seconds)

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._sock.close()
