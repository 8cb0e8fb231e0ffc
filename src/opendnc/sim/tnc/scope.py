"""Remote scope (iTNC 530): channel descriptions, signal details and sample blocks (§9).

Samples are generated from the machine model (axis positions, feed override, a sine for
channels without a live source) so a recording shows what the machine is doing.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

from opendnc.sim.tnc.machine import Machine

OSZI_CHSEL = 83
TOO_MANY_SIGNALS = 85
MAX_SIGNALS = 16
SAMPLES_PER_BLOCK = 32
INTERVALS = (600, 3000, 21000)


@dataclass(frozen=True, slots=True)
class Channel:
    """One scope channel: number, type (0, 1, 2, 4, 10), name and signal labels."""

    number: int
    kind: int
    name: str
    labels: tuple[str, ...]
    unit: str
    factor: float

    def describe(self) -> bytes:
        """``S_OC`` payload: 59 bytes (type 0), 90 (types 1/4) or 94 (types 2/10)."""
        head = struct.pack(">HHHHH", self.number, 600, self.kind, 0, 600) + b"\0" * 36
        head += self.name.encode("latin-1")[:12].ljust(13, b"\0")
        if self.kind == 0:
            return head
        total = 90 if self.kind in (1, 4) else 94
        labels = b"".join(label.encode("latin-1") + b"\0" for label in self.labels)
        return (head + labels).ljust(total, b"\0")[:total]


_AXES = ("X", "Y", "Z", "B", "C", "-", "-", "-")
CHANNELS = (
    Channel(0, 1, "s actual", _AXES, "mm", 0.0001),
    Channel(1, 1, "s nominal", _AXES, "mm", 0.0001),
    Channel(2, 1, "v actual", _AXES, "mm/min", 0.001),
    Channel(3, 4, "s diff", _AXES, "mm", 0.0001),
    Channel(4, 0, "F override", (), "%", 0.01),
    Channel(6, 2, "PLC", ("M", "T", "C", "I", "O", "B", "W", "D"), "", 1.0),
)


@dataclass(frozen=True, slots=True)
class Signal:
    """A selected signal: channel and signal index or PLC operand."""

    channel: Channel
    index: int
    operand_type: int = -1
    address: int = 0


def parse_selection(payload: bytes) -> tuple[int, list[Signal]]:
    """Decode ``R_OP``: interval and 8-byte selectors; ValueError(code) when invalid."""
    if len(payload) < 12 or (len(payload) - 4) % 8:
        raise ValueError(OSZI_CHSEL)
    interval = struct.unpack_from(">I", payload)[0]
    if interval not in INTERVALS:
        raise ValueError(OSZI_CHSEL)
    by_number = {c.number: c for c in CHANNELS}
    signals = []
    for off in range(4, len(payload), 8):
        number, sub, address = struct.unpack_from(">HHI", payload, off)
        channel = by_number.get(number)
        if channel is None:
            raise ValueError(OSZI_CHSEL)
        if channel.kind in (1, 4) and (sub >= len(channel.labels) or channel.labels[sub] == "-"):
            raise ValueError(OSZI_CHSEL)
        if channel.kind in (2, 10):
            signals.append(Signal(channel, 0, sub, address))
        else:
            signals.append(Signal(channel, sub if channel.kind else 0))
    if len(signals) > MAX_SIGNALS:
        raise ValueError(TOO_MANY_SIGNALS)
    return interval, signals


def signal_details(signals: list[Signal]) -> bytes:
    """``S_OP``: per signal 10-byte unit, f64le factor, i32 offset 0."""
    out = b""
    for s in signals:
        out += s.channel.unit.encode("latin-1")[:10].ljust(10, b"\0")
        out += struct.pack("<d", s.channel.factor) + b"\0\0\0\0"
    return out


def sample_block(machine: Machine, signals: list[Signal], sequence: int, interval: int) -> bytes:
    """``S_OD``: sequence number + per signal 32 raw samples."""
    machine.advance()
    positions = list(machine.positions.values())
    out = struct.pack(">I", sequence)
    t0 = sequence * SAMPLES_PER_BLOCK * interval / 1e6
    for s in signals:
        values = []
        for k in range(SAMPLES_PER_BLOCK):
            t = t0 + k * interval / 1e6
            kind = s.channel.number
            if kind in (0, 1) and s.index < len(positions):
                phys = positions[s.index] + (0.0005 * math.sin(40 * t) if kind == 0 else 0.0)
            elif kind == 2:
                phys = 600.0 * machine.feed_override / 10000 if machine.running else 0.0
            elif kind == 3:
                phys = 0.002 * math.sin(2 * math.pi * 5 * t)
            elif kind == 4:
                phys = machine.feed_override / 100
            else:
                phys = float(machine.plc.image[s.address % len(machine.plc.image)])
            raw = round(phys / s.channel.factor)
            values.append(max(-(2**31), min(2**31 - 1, raw)))
        out += struct.pack(">H", SAMPLES_PER_BLOCK) + b"\xff\xff\xff\xff"
        out += struct.pack(f">{SAMPLES_PER_BLOCK}i", *values)
    return out
