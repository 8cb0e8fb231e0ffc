"""``--trace``: print every telegram both ways, as hex and decoded."""

from __future__ import annotations

import struct
import sys
import time
from typing import TextIO

from opendnc.lsv2.framing import Frame, TelegramFramer

_TEXT_PAYLOAD = frozenset(
    [
        "A_LG",
        "A_LO",
        "C_DC",
        "C_DM",
        "C_DD",
        "C_FD",
        "C_FC",
        "C_FR",
        "R_FI",
        "C_NC",
        "R_MC",
        "S_MC",
        "S_VR",
    ]
)


def describe(frame: Frame) -> str:
    """A short human reading of a telegram."""
    p = frame.payload
    name = frame.mnemonic
    if name in ("T_ER", "T_BD") and len(p) == 2:
        return f"{name} error {p[1]}"
    if name in _TEXT_PAYLOAD or name in ("C_FL", "R_FL"):
        strings = [s.decode("latin-1") for s in p.split(b"\0") if s]
        return f"{name} {strings!r}"
    if name in ("R_RI", "C_EK") and len(p) == 2:
        return f"{name} {struct.unpack('>H', p)[0]}"
    if name == "C_CC" and len(p) >= 2:
        return f"{name} {struct.unpack_from('>H', p)[0]} {p[2:].rstrip(bytes(1))!r}"
    if name == "R_MB" and len(p) == 5:
        addr, count = struct.unpack(">IB", p)
        return f"{name} address {addr} count {count}"
    return f"{name} ({len(p)} bytes)"


class TraceHook:
    """Writes one line per telegram (direction, peer, decoded form) plus a hex dump."""

    def __init__(self, out: TextIO | None = None, max_hex: int = 64) -> None:
        self.out = out if out is not None else sys.stderr
        self.max_hex = max_hex

    def frame(self, peer: str, direction: str, frame: Frame) -> None:
        """Record one telegram; ``direction`` is ``<-`` (received) or ``->`` (sent)."""
        raw = TelegramFramer.encode(frame)
        shown = raw[: self.max_hex].hex(" ")
        more = f" …(+{len(raw) - self.max_hex})" if len(raw) > self.max_hex else ""
        stamp = time.strftime("%H:%M:%S")
        self.out.write(f"{stamp} {peer} {direction} {describe(frame)}\n    {shown}{more}\n")
        self.out.flush()

    def note(self, peer: str, text: str) -> None:
        """Record an event that is not a telegram."""
        self.out.write(f"{time.strftime('%H:%M:%S')} {peer} !! {text}\n")
        self.out.flush()
