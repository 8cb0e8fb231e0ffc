"""Typed events and the shared plumbing of the sans-IO XModem engines.

Both engines are driven the same way (see :mod:`opendnc.xmodem.driver`):

* feed bytes from the peer with ``receive_data(data)``;
* when ``timer`` has run out without new input, call ``timed_out()`` -- the engine never reads
  a clock; a timer is re-armed only when ``timer.serial`` changes, so line noise cannot keep a
  timeout from firing;
* if the link dies, call ``peer_closed()``;
* write ``data_to_send()`` to the peer and handle ``next_event()`` until it returns ``None``;
* stop when ``finished`` is true; ``error`` then holds the typed failure, if any.
"""

from __future__ import annotations

import enum
from collections import deque
from dataclasses import dataclass
from typing import NamedTuple

from opendnc.errors import DncError
from opendnc.xmodem.framing import CANCEL_BYTES, Mode


class Timer(NamedTuple):
    """Ask the driver to call ``timed_out()`` after ``seconds`` without a newer timer.

    ``listen`` is false for a pure pause (no input is expected meanwhile), which a driver may
    sleep through instead of reading. (A named tuple: one is made per block, so it must be
    cheap to create.)
    """

    serial: int
    seconds: float
    listen: bool = True


class EotAnswer(enum.Enum):
    """How the receiver answered the sender's EOT (a sender's Completed: what came back; a
    receiver's: what it sent, see ``ReceiverConfig.eot_answer``)."""

    ACK = "ack"  # the standard ending
    # a Haas answers a complete transfer with CAN CAN CAN (docs/xmodem.md#haas-captures, Figure 24)
    CAN = "can"
    NONE = "none"  # no answer after the EOT retries (lrzsz rx can lose its last ACK)
    CLOSED = "closed"  # the link closed after the EOT


@dataclass(frozen=True, slots=True)
class Started:
    """The peer's start request arrived (sender) or the first block arrived (receiver)."""

    mode: Mode
    crc: bool


@dataclass(frozen=True, slots=True)
class BlockDone:
    """Sender: block ``seq`` was acknowledged; ``done`` of ``total`` payload bytes delivered."""

    seq: int
    done: int
    total: int


@dataclass(frozen=True, slots=True)
class Retry:
    """A block, start request or EOT is being repeated; ``attempt`` counts from 1."""

    seq: int
    attempt: int
    reason: str


@dataclass(frozen=True, slots=True)
class FallbackToSmall:
    """Sender: 1K blocks failed repeatedly; the rest goes in 128-byte blocks."""

    seq: int


@dataclass(frozen=True, slots=True)
class DataReceived:
    """Receiver: file bytes in order, ready to be written out."""

    data: bytes


@dataclass(frozen=True, slots=True)
class Duplicate:
    """Receiver: block ``seq`` came again (our ACK was lost); it was ACKed and dropped."""

    seq: int


@dataclass(frozen=True, slots=True)
class Completed:
    """The transfer ended successfully."""

    size: int
    blocks: int
    eot_answer: EotAnswer = EotAnswer.ACK


@dataclass(frozen=True, slots=True)
class Failed:
    """The transfer ended with ``error`` (also raised by the drivers)."""

    error: DncError


Event = (
    Started | BlockDone | Retry | FallbackToSmall | DataReceived | Duplicate | Completed | Failed
)


class EngineBase:
    """Outgoing bytes, pending events, the timer and the finished/error state."""

    def __init__(self) -> None:
        # Outgoing bytes: a single chunk waits in _pending and goes out without a copy (the
        # common case: one block or one ACK per step); more chunks are joined in _out.
        self._pending: bytes | None = None
        self._out = bytearray()
        self._events: deque[Event] = deque()
        self._timer_serial = 0
        self.timer: Timer | None = None
        self.finished = False
        self.error: DncError | None = None
        self.result: Completed | None = None

    def data_to_send(self) -> bytes:
        """Bytes to write to the peer now (possibly empty)."""
        pending = self._pending
        if pending is not None:
            self._pending = None  # _out is always empty while a chunk is pending
            return pending
        if not self._out:
            return b""
        out = bytes(self._out)
        self._out.clear()
        return out

    def _emit(self, data: bytes) -> None:
        if self._pending is None and not self._out:
            self._pending = data
            return
        if self._pending is not None:
            self._out += self._pending
            self._pending = None
        self._out += data

    def prepare(self) -> None:
        """Do now, while the driver waits for the peer, work that the next input will need.

        Drivers call it after writing and before blocking on a read. What it does never shows
        on the wire or in events; engines without such work inherit this no-op.
        """

    @property
    def has_events(self) -> bool:
        """True while :meth:`next_event` has something to return."""
        return bool(self._events)

    def next_event(self) -> Event | None:
        """The next event, or ``None`` when there is none."""
        return self._events.popleft() if self._events else None

    def _arm(self, seconds: float, *, listen: bool = True) -> None:
        self._timer_serial += 1
        self.timer = Timer(self._timer_serial, seconds, listen)

    def _finish(self, event: Completed) -> None:
        self.finished = True
        self.timer = None
        self.result = event
        self._events.append(event)

    def _fail(self, error: DncError, *, cancel_peer: bool) -> None:
        if cancel_peer:
            self._emit(CANCEL_BYTES)
        self.finished = True
        self.timer = None
        self.error = error
        self._events.append(Failed(error))
