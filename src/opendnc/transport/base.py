"""The blocking byte-stream interface shared by all transports."""

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
