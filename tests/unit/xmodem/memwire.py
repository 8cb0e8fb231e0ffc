"""Two XModem engines wired in memory under a virtual clock, with an optional fault hook.

Used by the unit and property tests: nothing sleeps, a 10 s timeout costs no real time, and
a run that does not finish within ``max_time`` virtual seconds is reported as a hang.
"""

from __future__ import annotations

import heapq
import itertools
from collections.abc import Callable
from dataclasses import dataclass, field

from opendnc.errors import DncError
from opendnc.xmodem.events import Completed, DataReceived, Event
from opendnc.xmodem.receiver import XmodemReceiver
from opendnc.xmodem.sender import XmodemSender

Engine = XmodemSender | XmodemReceiver
# fault(direction, data) -> bytes actually delivered; direction is "s>r" or "r>s"
Fault = Callable[[str, bytes], bytes]


@dataclass
class WireResult:
    """Outcome of a wired run."""

    received: bytes
    sender_result: Completed | None
    receiver_result: Completed | None
    sender_error: DncError | None
    receiver_error: DncError | None
    elapsed: float
    sender_events: list[Event] = field(default_factory=list)
    receiver_events: list[Event] = field(default_factory=list)
    trace: list[tuple[float, str, bytes]] = field(default_factory=list)


class Hang(AssertionError):
    """The engines stopped making progress without finishing."""


def run_wired(
    sender: XmodemSender,
    receiver: XmodemReceiver,
    *,
    fault: Fault | None = None,
    latency: float = 0.001,
    byte_time: float = 0.0,
    max_time: float = 100_000.0,
    keep_trace: bool = False,
    prepare: bool = True,
) -> WireResult:
    """Run both engines until both have finished (or raise :class:`Hang`).

    ``prepare`` calls each engine's :meth:`prepare` after it has sent, as the drivers do.
    """
    now = 0.0
    seq = itertools.count()
    inflight: list[tuple[float, int, str, bytes]] = []  # (deliver_at, order, direction, data)
    deadlines: dict[str, tuple[int, float]] = {}
    received = bytearray()
    result = WireResult(b"", None, None, None, None, 0.0)
    engines: dict[str, Engine] = {"s": sender, "r": receiver}
    line_free = {"s>r": 0.0, "r>s": 0.0}

    def pump(name: str) -> None:
        engine = engines[name]
        while (event := engine.next_event()) is not None:
            if name == "r":
                result.receiver_events.append(event)
                if isinstance(event, DataReceived):
                    received.extend(event.data)
            else:
                result.sender_events.append(event)
        out = engine.data_to_send()
        if out:
            direction = "s>r" if name == "s" else "r>s"
            if keep_trace:
                result.trace.append((now, direction, out))
            data = fault(direction, out) if fault is not None else out
            if data:
                start = max(now, line_free[direction])
                done = start + len(data) * byte_time
                line_free[direction] = done
                heapq.heappush(inflight, (done + latency, next(seq), direction, data))
        if prepare:
            engine.prepare()
        timer = engine.timer
        if engine.finished or timer is None:
            deadlines.pop(name, None)
        elif deadlines.get(name, (-1, 0.0))[0] != timer.serial:
            deadlines[name] = (timer.serial, now + timer.seconds)

    pump("s")
    pump("r")
    while not (sender.finished and receiver.finished):
        candidates = [(at, name) for name, (_, at) in deadlines.items()]
        if inflight:
            candidates.append((inflight[0][0], "wire"))
        if not candidates:
            raise Hang(f"no timer and nothing in flight: {sender.state}, {receiver.state}")
        at, what = min(candidates)
        now = max(now, at)
        if now > max_time:
            raise Hang(f"still running after {max_time} virtual seconds")
        if what == "wire":
            _, _, direction, data = heapq.heappop(inflight)
            target = "r" if direction == "s>r" else "s"
            engines[target].receive_data(data)
            pump(target)
        else:
            deadlines.pop(what)
            engines[what].timed_out()
            pump(what)
        # once one side is done, the other can only finish by its own timers or bytes
    result.received = bytes(received)
    result.sender_result, result.receiver_result = sender.result, receiver.result
    result.sender_error, result.receiver_error = sender.error, receiver.error
    result.elapsed = now
    return result
