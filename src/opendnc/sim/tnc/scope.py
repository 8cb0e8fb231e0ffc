"""Remote scope (iTNC 530): channel descriptions, signal details and sample blocks
(docs/lsv2.md#remote-scope).

Samples are generated from the machine model (axis positions, feed override, a sine for
channels without a live source) so a recording shows what the machine is doing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from opendnc.errors import ControlRefused
from opendnc.lsv2.constants import ErrorCode as E
from opendnc.lsv2.payloads import ScopeChannel, ScopeSamples, ScopeSignal, ScopeSignalInfo
from opendnc.sim.tnc.machine import Machine

OSZI_CHSEL = E.T_ER_OSZI_CHSEL
TOO_MANY_SIGNALS = E.T_ER_TOO_MANY_SIGNALS
MAX_SIGNALS = 16
SAMPLES_PER_BLOCK = 32
INTERVALS = (600, 3000, 21000)  # the only intervals pyLSV2 and TNCscope use


@dataclass(frozen=True, slots=True)
class Channel:
    """One scope channel: number, type (0, 1, 2, 4, 10), name and signal labels."""

    number: int
    kind: int
    name: str
    labels: tuple[str, ...]
    unit: str
    factor: float

    def describe(self) -> ScopeChannel:
        """The codec's ``S_OC`` description, padded to the captured lengths."""
        total = 59 if self.kind == 0 else 90 if self.kind in (1, 4) else 94
        return PaddedChannel(self.number, 600, self.kind, self.name, self.labels, total)


@dataclass(frozen=True, slots=True)
class PaddedChannel(ScopeChannel):
    """Real controls send fixed-size descriptions (59, 90 or 94 bytes): pad the labels."""

    total: int = 59

    def to_bytes(self) -> bytes:
        """The codec's layout, NUL-padded to ``total`` bytes."""
        return ScopeChannel.to_bytes(self).ljust(self.total, b"\0")


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


def parse_selection(selectors: tuple[ScopeSignal, ...]) -> list[Signal]:
    """Check ``R_OP`` selectors; ControlRefused with the LSV2 code when invalid."""
    if not selectors:
        raise ControlRefused(OSZI_CHSEL, "bad scope selection")
    if len(selectors) > MAX_SIGNALS:
        raise ControlRefused(TOO_MANY_SIGNALS, "bad scope selection")
    by_number = {c.number: c for c in CHANNELS}
    signals = []
    for sel in selectors:
        channel = by_number.get(sel.channel)
        if channel is None:
            raise ControlRefused(OSZI_CHSEL, "bad scope selection")
        if channel.kind in (1, 4):
            if sel.selector >= len(channel.labels) or channel.labels[sel.selector] == "-":
                raise ControlRefused(OSZI_CHSEL, "bad scope selection")
            signals.append(Signal(channel, sel.selector))
        elif channel.kind in (2, 10):
            signals.append(Signal(channel, 0, sel.selector, sel.address))
        else:
            signals.append(Signal(channel, 0))
    return signals


def signal_details(signals: list[Signal]) -> tuple[ScopeSignalInfo, ...]:
    """``S_OP`` records: unit, scale factor, offset 0."""
    return tuple(ScopeSignalInfo(s.channel.unit, s.channel.factor, 0) for s in signals)


def sample_blocks(
    machine: Machine, signals: list[Signal], sequence: int, interval: int
) -> tuple[ScopeSamples, ...]:
    """One ``S_OD`` worth of samples: 32 raw values per selected signal."""
    machine.advance()
    positions = list(machine.positions.values())
    running = machine.running
    t0 = sequence * SAMPLES_PER_BLOCK * interval / 1e6
    blocks = []
    for s in signals:
        values = []
        for k in range(SAMPLES_PER_BLOCK):
            t = t0 + k * interval / 1e6
            kind = s.channel.number
            if kind in (0, 1) and s.index < len(positions):
                phys = positions[s.index] + (0.0005 * math.sin(40 * t) if kind == 0 else 0.0)
            elif kind == 2:
                phys = 600.0 * machine.feed_override / 10000 if running else 0.0
            elif kind == 3:
                phys = 0.002 * math.sin(2 * math.pi * 5 * t)
            elif kind == 4:
                phys = machine.feed_override / 100
            else:
                phys = float(machine.plc.image[s.address % len(machine.plc.image)])
            raw = round(phys / s.channel.factor)
            values.append(max(-(2**31), min(2**31 - 1, raw)))
        blocks.append(ScopeSamples(tuple(values)))
    return tuple(blocks)
