"""The loop watch records a callback that blocks the event loop, and what it did meanwhile
(docs/server.md#event-loop-stalls); and the event bus hands over a backlog in one go."""

from __future__ import annotations

import asyncio
import time

from opendnc.server.core.events import EventBus, JobQueued
from opendnc.server.core.jobwords import JobKind
from opendnc.server.core.loopwatch import LoopWatch


def test_a_blocking_call_on_the_loop_is_a_stall_in_which_the_thread_did_not_run() -> None:
    async def scenario() -> LoopWatch:
        watch = LoopWatch(interval=0.05, warn=60.0)
        task = asyncio.create_task(watch.run())
        while watch.wakes < 2:  # the watch is asleep on the loop
            await asyncio.sleep(0.01)
        time.sleep(0.4)  # a blocking call on the loop: nothing else runs meanwhile
        wakes = watch.wakes
        while watch.wakes == wakes:
            await asyncio.sleep(0.01)
        task.cancel()
        return watch

    watch = asyncio.run(scenario())
    longest = watch.longest()[0]
    assert longest.seconds >= 0.3  # slept 0.4 s while at most 0.05 s of its wait was left
    assert longest.run < longest.seconds / 2  # asleep, not computing
    shown = watch.as_json()
    assert shown["longest_stalls"][0]["seconds"] == round(longest.seconds, 3)
    assert shown["recent_stalls"][-1]["at"] == longest.at.isoformat()


def test_a_subscriber_drains_its_backlog_oldest_first() -> None:
    async def scenario() -> list[str]:
        bus = EventBus()
        bus.bind(asyncio.get_running_loop())
        with bus.subscribe(maxsize=10) as sub:
            for n in range(4):
                bus.publish(JobQueued(n, "m", JobKind.SEND))
            first = await sub.next()
            rest = sub.drain()
            assert sub.drain() == []
            return [first.key] + [e.key for e in rest]

    assert asyncio.run(scenario()) == ["0:queued", "1:queued", "2:queued", "3:queued"]
