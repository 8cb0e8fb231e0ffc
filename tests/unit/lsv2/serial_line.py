"""A simulated serial line between two :class:`SerialLink` engines, on a virtual clock.

Each lane delivers bytes one character time apart; a fault function may drop, duplicate or
change each character. Used by the engine's unit and property tests.
"""

from __future__ import annotations

import heapq
import itertools
from collections.abc import Callable
from dataclasses import dataclass, field

from opendnc.lsv2.framing import Frame
from opendnc.lsv2.serial_link import (
    LinkFailed,
    LinkRole,
    LinkTiming,
    SerialLink,
    TelegramReceived,
    TelegramSent,
)

CHAR_TIME = 11 / 57600  # one 8E1 character at 57600 baud
Fault = Callable[[int], list[int]]  # one character in, what arrives out
MARKED = 0x100
"""Added to a character a fault delivers: the port marked it as failing its parity check."""


def clean(b: int) -> list[int]:
    """No fault: the character arrives as sent."""
    return [b]


@dataclass
class Lane:
    """One direction of the line."""

    fault: Fault = clean
    free_at: float = 0.0
    log: list[int] = field(default_factory=list)


@dataclass
class Outcome:
    """What an exchange of requests and echoed answers produced."""

    answers: list[bytes]
    served: list[bytes]
    failure: str | None
    client: SerialLink
    control: SerialLink
    end_time: float
    to_control: list[int]
    to_client: list[int]


def echo(_index: int, request: Frame) -> Frame:
    """The default control: answer ``R_XX`` + payload with ``S_XX`` + the same payload."""
    return Frame("S_XX", request.payload)


def exchange(
    requests: list[bytes],
    *,
    up: Fault = clean,
    down: Fault = clean,
    timing: LinkTiming | None = None,
    retries: int = 3,
    link_check: bool = False,
    answer_timeout: float = 60.0,
    horizon: float = 3600.0,
    answer: Callable[[int, Frame], Frame] = echo,
    mnemonic: str = "R_XX",
) -> Outcome:
    """Client sends each request (as telegram ``mnemonic`` + payload) once the previous answer
    came; the control answers the ``i``-th delivered request with ``answer(i, request)``
    (by default ``S_XX`` + the same payload). ``served`` and ``answers`` hold payloads."""
    kwargs = {"timing": timing} if timing else {}
    client = SerialLink(LinkRole.CLIENT, retries=retries, **kwargs)
    control = SerialLink(LinkRole.CONTROL, retries=retries, **kwargs)
    lanes = {"up": Lane(up), "down": Lane(down)}
    queue: list[tuple[float, int, str, int]] = []  # (time, seq, lane, byte)
    seq = itertools.count()
    now = 0.0
    answers: list[bytes] = []
    served: list[bytes] = []
    failure: str | None = None
    pending = list(requests)
    waiting_since: float | None = None

    def put(lane_name: str, data: bytes) -> None:
        lane = lanes[lane_name]
        for b in data:
            lane.free_at = max(lane.free_at, now) + CHAR_TIME
            for out in lane.fault(b):
                lane.log.append(out)
                heapq.heappush(queue, (lane.free_at, next(seq), lane_name, out))

    def flush() -> None:
        put("up", client.data_to_send())
        put("down", control.data_to_send())

    def next_request() -> None:
        nonlocal waiting_since
        if pending:
            client.send(Frame(mnemonic, pending.pop(0)), now)
            waiting_since = now
        else:
            waiting_since = None

    if link_check:
        client.check_link(now)
    next_request()
    flush()
    while failure is None and (waiting_since is not None or queue):
        # events of both engines
        while (ev := control.next_event()) is not None:
            if isinstance(ev, TelegramReceived):
                control.send(answer(len(served), ev.frame), now)
                served.append(ev.frame.payload)
        while (ev := client.next_event()) is not None:
            if isinstance(ev, TelegramReceived):
                answers.append(ev.frame.payload)
                next_request()
            elif isinstance(ev, LinkFailed) and ev.frame is not None:
                failure = str(ev.error)
            elif isinstance(ev, TelegramSent):
                pass
        flush()
        if failure is not None:
            break
        times = [t for t in (client.deadline, control.deadline) if t is not None]
        if queue:
            times.append(queue[0][0])
        if waiting_since is not None:
            times.append(waiting_since + answer_timeout)
        if not times:
            break
        now = max(now, min(times))
        if now > horizon:
            failure = "horizon"
            break
        if waiting_since is not None and now >= waiting_since + answer_timeout:
            failure = "answer timeout"
            break
        while queue and queue[0][0] <= now:
            _, _, lane_name, b = heapq.heappop(queue)
            errors = (0,) if b & MARKED else ()
            (control if lane_name == "up" else client).receive_data(bytes([b & 0xFF]), now, errors)
        client.tick(now)
        control.tick(now)
    return Outcome(
        answers,
        served,
        failure,
        client,
        control,
        now,
        lanes["up"].log,
        lanes["down"].log,
    )
