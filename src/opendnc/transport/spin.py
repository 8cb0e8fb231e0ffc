"""Adaptive busy-polling before a blocking read.

A request/response protocol spends most of a transfer waiting for the peer's answer. When the
answer comes back within tens of microseconds (a simulator on loopback, a fast serial server),
putting the process to sleep and waking it again costs as much as the answer itself: on a VM an
idle vCPU takes 20-60 µs to wake. Polling the socket or port for a short while first keeps the
CPU awake and cuts the round trip.

The policy spins only while it pays. It keeps a smoothed average of how long recent reads
waited; when answers take longer than the spin window (a real control over Ethernet answers in
a millisecond or more, a serial line in character times), it stops spinning and only measures,
so a slow link costs two clock reads per read and no CPU. It never spins when the process may
use one CPU only (spinning would keep the peer from running), and it yields the CPU between
polls, so a peer on the same CPU still gets to answer.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from typing import TypeVar

T = TypeVar("T")

DEFAULT_WINDOW = 100e-6  # seconds: longer than a loopback round trip, far below a real control's
_SMOOTHING = 0.25  # weight of the newest wait in the average


def _several_cpus() -> bool:
    try:
        return len(os.sched_getaffinity(0)) > 1
    except (AttributeError, OSError):  # not on Linux: trust the CPU count
        return (os.cpu_count() or 1) > 1


class BusyPoll:
    """Decides whether a read spins before it blocks, and does the spinning.

    ``window`` is the longest spin in seconds; 0 turns spinning off. A stream calls
    :meth:`read` with a non-blocking attempt and its blocking read.
    """

    __slots__ = ("_average", "enabled", "window")

    def __init__(self, window: float = DEFAULT_WINDOW) -> None:
        self.window = window
        # sched_yield is POSIX; where it is missing (Windows) reads simply block
        self.enabled = window > 0 and hasattr(os, "sched_yield") and _several_cpus()
        self._average = 0.0

    @property
    def active(self) -> bool:
        """True when the next read should spin: recent answers came within the window."""
        return self.enabled and self._average <= self.window

    def spin(self, attempt: Callable[[], T | None], started: float) -> T | None:
        """Call ``attempt`` until it returns a value or the window since ``started`` is over."""
        end = started + self.window
        clock, pause = time.perf_counter, os.sched_yield
        while True:
            result = attempt()
            if result is not None:
                return result
            if clock() >= end:
                return None
            pause()

    def read(self, attempt: Callable[[], T | None], block: Callable[[], T]) -> T:
        """One read: spin on ``attempt`` while that pays, else (or then) ``block``.

        The whole wait is recorded, also when ``block`` raises (a timeout is a long wait).
        """
        started = time.perf_counter()
        try:
            if self.active:
                result = self.spin(attempt, started)
                if result is not None:
                    return result
            return block()
        finally:
            self.record(time.perf_counter() - started)

    def record(self, waited: float) -> None:
        """Report how long a read waited for its data (spinning included)."""
        self._average += (waited - self._average) * _SMOOTHING
