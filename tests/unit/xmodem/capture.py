"""Parser for the Haas XModem sniffer dumps in docs/captures/haas-xmodem-opendnc.txt."""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

CAPTURE = Path(__file__).resolve().parents[3] / "docs" / "captures" / "haas-xmodem-opendnc.txt"
_HEAD = re.compile(r"^\[(\d\d/\d\d/\d{4} \d\d:\d\d:\d\d)\] (Written|Read) data \(COM2\)")
_HEX = re.compile(r"^    ((?:[0-9a-f]{2} ){0,15}[0-9a-f]{2})(?: {2,}|$)")


@dataclass(frozen=True)
class Chunk:
    """One sniffer record: ``pc_wrote`` is True for bytes the PC sent to the control."""

    stamp: str
    pc_wrote: bool
    data: bytes


def load(figure: int) -> list[Chunk]:
    """The records of Figure 23 (control sends) or 24 (PC sends), in order."""
    chunks: list[Chunk] = []
    inside = False
    for line in CAPTURE.read_text(encoding="utf-8").splitlines():
        if line.startswith("== figure"):
            inside = line == f"== figure {figure}"
            continue
        if not inside:
            continue
        head = _HEAD.match(line)
        if head:
            chunks.append(Chunk(head.group(1), head.group(2) == "Written", b""))
            continue
        hexes = _HEX.match(line)
        if hexes and chunks:
            last = chunks[-1]
            chunks[-1] = Chunk(last.stamp, last.pc_wrote, last.data + bytes.fromhex(hexes.group(1)))
    return chunks
