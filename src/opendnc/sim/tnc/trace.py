"""``--trace``: print every telegram both ways, as hex and decoded."""

from __future__ import annotations

import sys
import time
from typing import TextIO

from opendnc.lsv2.framing import Frame, TelegramFramer


class TraceHook:
    """Writes one line per telegram (time, peer, direction, decoded form) plus a hex dump."""

    def __init__(self, out: TextIO | None = None, max_hex: int = 64) -> None:
        self.out = out if out is not None else sys.stderr
        self.max_hex = max_hex

    def raw(self, peer: str, direction: str, frame: Frame, decoded: str) -> None:
        """Record a received frame with its decoded reading."""
        self.wire(peer, direction, TelegramFramer.encode(frame), decoded)

    def wire(self, peer: str, direction: str, data: bytes, decoded: str) -> None:
        """Record telegram bytes; ``direction`` is ``<-`` (received) or ``->`` (sent)."""
        shown = data[: self.max_hex].hex(" ")
        more = f" ...(+{len(data) - self.max_hex} bytes)" if len(data) > self.max_hex else ""
        if len(decoded) > 200:
            decoded = decoded[:200] + "..."
        stamp = time.strftime("%H:%M:%S")
        self.out.write(f"{stamp} {peer} {direction} {decoded}\n    {shown}{more}\n")
        self.out.flush()

    def note(self, peer: str, text: str) -> None:
        """Record an event that is not a telegram."""
        self.out.write(f"{time.strftime('%H:%M:%S')} {peer} !! {text}\n")
        self.out.flush()
