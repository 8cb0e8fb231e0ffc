"""Seeded line faults for one direction of the virtual cable: bit errors and dropped bytes.

Pure and deterministic: no I/O, no clock. The fate of a byte depends only on its position in
the stream of the direction and on the seed, never on how the stream is cut into chunks. That
is what makes a faulty run reproducible although the pump reads whatever the pty happens to
hold.

Model:

* every data bit (8 per character) flips independently with probability ``ber``; start, stop
  and parity bits are not modelled (a hit there shows up on a real UART as a framing error,
  which :attr:`LineNoise.drop_rate` stands in for);
* every character is lost independently with probability ``drop_rate`` (overrun, framing
  error, a glitch swallowing a start bit). A dropped character still used its time on the line.

Rare events are placed by drawing the gap to the next one from a geometric distribution, so the
cost is per fault, not per bit.

With ``parity_check`` the line also carries a parity bit: a character with an odd number of
flipped data bits fails the receiving UART's check (:attr:`NoiseResult.parity_errors`), and
:func:`uart_input` hands it over the way the receiver's port settings ask for
(docs/lsv2-serial.md, "Parity errors"): unchanged, as NUL, dropped, or marked ``FF 00 c``.
"""

from __future__ import annotations

import bisect
import enum
import math
import random
from collections.abc import Sequence
from dataclasses import dataclass

from opendnc.errors import InputError

DATA_BITS = 8


@dataclass(frozen=True, slots=True)
class NoiseResult:
    """What the line did to one chunk: the bytes that arrive and what went wrong."""

    data: bytes
    corrupted: int  # delivered bytes with at least one flipped bit
    dropped: int  # bytes lost on the way
    bit_flips: int  # flipped bits in delivered bytes
    parity_errors: tuple[int, ...] = ()  # indices into data failing the parity check


class UartInput(enum.Enum):
    """What a POSIX port hands over for a character that failed its parity check (termios)."""

    RAW = "raw"  # INPCK off: the character as read, nobody looked at the parity bit
    NUL = "nul"  # INPCK: a NUL instead
    DROP = "drop"  # INPCK and IGNPAR: nothing
    MARK = "mark"  # INPCK and PARMRK: FF 00 c, and every good FF doubled


def uart_input(data: bytes, parity_errors: Sequence[int], mode: UartInput) -> bytes:
    """The bytes a reader gets for ``data`` whose characters at ``parity_errors`` failed."""
    if mode is UartInput.MARK:
        bad = set(parity_errors)
        if not bad:
            return data.replace(b"\xff", b"\xff\xff")
        out = bytearray()
        for i, c in enumerate(data):
            if i in bad:
                out += b"\xff\x00"
                out.append(c)
            elif c == 0xFF:
                out += b"\xff\xff"
            else:
                out.append(c)
        return bytes(out)
    if not parity_errors or mode is UartInput.RAW:
        return data
    buf = bytearray(data)
    if mode is UartInput.NUL:
        for i in parity_errors:
            buf[i] = 0
        return bytes(buf)
    for i in sorted(parity_errors, reverse=True):
        del buf[i]
    return bytes(buf)


class _EventStream:
    """Positions of independent Bernoulli(p) events along an endless sequence of slots."""

    def __init__(self, probability: float, rng: random.Random) -> None:
        self._rng = rng
        # log(1 - p), precomputed; None means the event never happens
        self._log_q: float | None = None
        self._always = probability >= 1.0
        if 0.0 < probability < 1.0:
            self._log_q = math.log1p(-probability)
        self.next_at: int | None = None
        if self._always:
            self.next_at = 0
        elif self._log_q is not None:
            self.next_at = self._gap()

    def _gap(self) -> int:
        assert self._log_q is not None
        # geometric: the number of quiet slots before the next event
        u = self._rng.random()
        return int(math.log1p(-u) / self._log_q)

    def advance(self) -> None:
        """Move past the current event to the next one."""
        assert self.next_at is not None
        if self._always:
            self.next_at += 1
        else:
            self.next_at += 1 + self._gap()


class LineNoise:
    """Bit errors and dropped bytes for one direction, reproducible from ``seed``.

    ``seed`` may be any int or str; ``None`` draws a fresh one from the OS. Two instances with
    the same arguments produce the same faults at the same byte positions.
    """

    def __init__(
        self,
        ber: float = 0.0,
        drop_rate: float = 0.0,
        seed: int | str | None = None,
        *,
        parity_check: bool = False,
    ):
        for name, value in (("bit-error rate", ber), ("drop rate", drop_rate)):
            if not 0.0 <= value <= 1.0 or math.isnan(value):
                raise InputError(f"{name} must be between 0 and 1, got {value}")
        self.ber = ber
        self.drop_rate = drop_rate
        self.parity_check = parity_check
        """Model the parity bit: a character with an odd number of flipped data bits fails the
        receiving UART's check and is listed in :attr:`NoiseResult.parity_errors` (what the
        reader then gets is :func:`uart_input`'s business). An even number of flips passes
        unnoticed, as on a real line."""
        base = random.SystemRandom().getrandbits(64) if seed is None else seed
        # separate generators: flips and drops stay independent of each other's draws
        self._flips = _EventStream(ber, random.Random(f"{base}:bits"))
        self._drops = _EventStream(drop_rate, random.Random(f"{base}:drops"))
        self.position = 0  # bytes processed so far

    @property
    def is_clean(self) -> bool:
        """True when this line never alters anything."""
        return self._flips.next_at is None and self._drops.next_at is None

    def apply(self, data: bytes) -> NoiseResult:
        """Pass ``data`` over the line and return what comes out of the far end."""
        start = self.position
        end = start + len(data)
        self.position = end
        if self.is_clean:
            return NoiseResult(bytes(data), 0, 0, 0)
        buf = bytearray(data)
        flipped: dict[int, int] = {}  # index in buf -> number of flipped bits
        flips = self._flips
        while flips.next_at is not None and flips.next_at < end * DATA_BITS:
            index, bit = divmod(flips.next_at, DATA_BITS)
            buf[index - start] ^= 1 << bit
            flipped[index - start] = flipped.get(index - start, 0) + 1
            flips.advance()
        dropped: list[int] = []
        drops = self._drops
        while drops.next_at is not None and drops.next_at < end:
            dropped.append(drops.next_at - start)
            drops.advance()
        for index in dropped:
            flipped.pop(index, None)
        bad: list[int] = []
        if self.parity_check:
            gone = sorted(dropped)
            for index, count in sorted(flipped.items()):
                if count % 2:
                    # its position once the dropped characters before it are gone
                    bad.append(index - _count_below(gone, index))
        for index in reversed(dropped):
            del buf[index]
        return NoiseResult(
            bytes(buf), len(flipped), len(dropped), sum(flipped.values()), tuple(bad)
        )


def _count_below(sorted_values: list[int], limit: int) -> int:
    return bisect.bisect_left(sorted_values, limit)
