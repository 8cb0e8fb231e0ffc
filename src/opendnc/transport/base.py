"""The blocking byte-stream interfaces shared by all transports."""

from __future__ import annotations

from typing import Protocol


class ByteStream(Protocol):
    """A bidirectional blocking byte stream."""

    def read(self, max_bytes: int) -> bytes:
        """Return 1..max_bytes bytes; raise TransportTimeout or PeerClosed otherwise."""
        ...

    def write(self, data: bytes) -> None:
        """Send all of ``data``."""
        ...

    def close(self) -> None:
        """Release the link; safe to call twice."""
        ...

    def set_timeout(self, seconds: float | None) -> None:
        """Change the read timeout (``None`` waits forever)."""
        ...


class PortStream(ByteStream, Protocol):
    """A :class:`ByteStream` that is a port of its own: what :func:`opendnc.transport.open_stream`
    returns. Drip-feed needs the two extra calls to look for an XOFF between writes without
    waiting, and to pace its writes by the line rather than by the driver's buffer."""

    def read_nowait(self, max_bytes: int) -> bytes:
        """Return up to ``max_bytes`` bytes that have already arrived, ``b""`` if none have;
        never waits. Raises PeerClosed when the peer is gone."""
        ...

    def drain(self) -> None:
        """Wait until everything written has left the port (a no-op where the link has no
        line of its own, such as TCP: the kernel took the data when ``write`` returned)."""
        ...
