"""The cyclic garbage collector paused while a question builds a large answer.

A year of utilization for 200 machines builds tens of thousands of small objects (the
figures of each machine and week, a JSON object for each) that all live until the answer
is sent. CPython's collector counts the objects that survive its young collections and,
once they reach a quarter of those already old, walks every object of the process: one or
two such walks per answer, about a third of its CPU time in a small server process. These
objects form no cycles (their reference counts free them when the answer is sent), so the
collector is paused while any question builds one and resumes when the last is done.
"""

from __future__ import annotations

import gc
import threading
from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["paused"]

_lock = threading.Lock()
_inside = 0  # questions building now (threads of the server's pool)
_resume = False  # whether the collector ran when the first of them began


@contextmanager
def paused() -> Iterator[None]:
    """Pause the cyclic collector for the ``with`` block; objects are still freed by their
    reference counts."""
    global _inside, _resume
    with _lock:
        if _inside == 0:
            _resume = gc.isenabled()
            gc.disable()
        _inside += 1
    try:
        yield
    finally:
        with _lock:
            _inside -= 1
            if _inside == 0 and _resume:
                gc.enable()
