"""The event bus: a cancel always ends a loop that waits for events, typed events carry what
their consumers need, and one helper times every server-sent-events stream.

The cancellation tests hit the racy moment on purpose: an event is delivered and the waiting
task is cancelled in the same turn of the loop. On Python 3.11 ``asyncio.wait_for`` around a
queue get returns the event and drops the cancel there (the control test shows the harness
reaches that moment), and a server whose status timeline looped so never stopped.
"""

from __future__ import annotations

import asyncio
import contextlib
import sys
from collections.abc import Awaitable, Callable
from datetime import UTC, datetime

from opendnc.server.config.shop import MqttConfig, MtconnectConfig
from opendnc.server.core.events import (
    Event,
    EventBus,
    JobFinished,
    JobProgress,
    JobQueued,
    JobStarted,
    MachineStatusChanged,
    ProgramChanged,
    stored_progress,
)
from opendnc.server.core.jobwords import JobKind, JobState
from opendnc.server.core.status import MachineStatus
from opendnc.server.http.streams import KEEP_ALIVE_COMMENT, throttled_stream
from opendnc.server.machines.timeline import Timeline

ROUNDS = 200
DEADLINE = 2.0  # seconds a cancelled loop may take to end


def _status_event(execution: str = "READY") -> MachineStatusChanged:
    status = MachineStatus(at=datetime.now(UTC), available=True, execution=execution)
    return MachineStatusChanged("m1", True, status)


async def _cancel_at_the_racy_moment(
    bus: EventBus,
    start: Callable[[], Awaitable[object]],
    *,
    rounds: int = ROUNDS,
    deadline: float = DEADLINE,
) -> int:
    """Start the loop, let it wait, then deliver an event and cancel it in one step;
    how many of ``rounds`` loops did not end within :data:`DEADLINE`."""
    stuck = 0
    for n in range(rounds):
        task = asyncio.ensure_future(start())
        for _ in range(3):  # into its wait (a loop may take a step or two to get there)
            await asyncio.sleep(0)
        bus.publish(_status_event("ACTIVE" if n % 2 else "READY"))
        task.cancel()
        done, _ = await asyncio.wait({task}, timeout=deadline)
        if not done:
            stuck += 1
            task.cancel()
            with contextlib.suppress(BaseException):
                await asyncio.wait({task}, timeout=DEADLINE)
        else:
            assert task.cancelled(), "a cancelled loop ended some other way"
    return stuck


def _run(scenario: Callable[[EventBus], Awaitable[int]]) -> int:
    async def main() -> int:
        bus = EventBus()
        bus.bind(asyncio.get_running_loop())
        return await scenario(bus)

    return asyncio.run(main())


def test_the_status_timeline_ends_when_cancelled_as_an_event_arrives() -> None:
    async def scenario(bus: EventBus) -> int:
        timeline = Timeline()

        async def listen() -> None:
            with bus.subscribe(maxsize=100) as sub:
                await timeline._listen(sub)

        return await _cancel_at_the_racy_moment(bus, listen)

    assert _run(scenario) == 0


def test_a_throttled_stream_ends_when_cancelled_as_an_event_arrives() -> None:
    class Source:
        async def snapshot(self, overflow: bool) -> bytes:
            return b""

        def take(self, event: Event) -> None:
            pass

        async def flush(self) -> bytes:
            return b""

    async def never() -> bool:
        return False

    async def scenario(bus: EventBus) -> int:
        async def read() -> None:
            async for _ in throttled_stream(bus, Source(), interval=0.05, disconnected=never):
                pass

        return await _cancel_at_the_racy_moment(bus, read)

    assert _run(scenario) == 0


def test_the_outputs_end_when_cancelled_as_an_event_arrives() -> None:
    from opendnc.server.outputs.mqtt import MqttPublisher
    from opendnc.server.outputs.shdr import MtconnectOutput

    async def scenario(bus: EventBus) -> int:
        publisher = MqttPublisher(MqttConfig(host="127.0.0.1"), "dnc", ["m1"], bus)
        mtconnect = MtconnectOutput(MtconnectConfig("127.0.0.1", {"m1": 0}), ["m1"], bus)

        async def follow() -> None:
            with bus.subscribe() as sub:
                await publisher._follow(sub)

        stuck = await _cancel_at_the_racy_moment(bus, follow)
        return stuck + await _cancel_at_the_racy_moment(bus, mtconnect.run)

    assert _run(scenario) == 0


def test_the_harness_reaches_the_moment_where_wait_for_drops_a_cancel() -> None:
    # The loop this module's fix replaced: on Python 3.11 it survives its cancel.
    async def scenario(bus: EventBus) -> int:
        async def old_loop() -> None:
            queue: asyncio.Queue[Event] = asyncio.Queue()
            with bus.subscribe() as sub:
                original = sub.put

                def put(event: Event) -> None:
                    original(event)
                    queue.put_nowait(event)

                sub.put = put  # type: ignore[method-assign]
                while True:
                    with contextlib.suppress(TimeoutError):
                        await asyncio.wait_for(queue.get(), 1.0)

        return await _cancel_at_the_racy_moment(bus, old_loop, rounds=5, deadline=0.3)

    survived = _run(scenario)
    if sys.version_info >= (3, 12):
        assert survived == 0  # wait_for was rewritten on asyncio.timeout and keeps the cancel
    else:
        assert survived > 0


def test_a_get_with_a_deadline_returns_none_then_the_next_event() -> None:
    async def scenario(bus: EventBus) -> list[object]:
        with bus.subscribe(maxsize=2) as sub:
            quiet = await sub.get(0.01)
            at_once = await sub.get(0)
            for n in range(3):  # one more than it holds: the oldest goes
                bus.publish(ProgramChanged(f"O{n}"))
            first = await sub.get(5)
            return [quiet, at_once, sub.take_overflow(), sub.take_overflow(), first, sub.drain()]

    async def main() -> list[object]:
        bus = EventBus()
        bus.bind(asyncio.get_running_loop())
        return await scenario(bus)

    quiet, at_once, overflowed, again, first, rest = asyncio.run(main())
    assert (quiet, at_once, overflowed, again) == (None, None, True, False)
    assert first == ProgramChanged("O1")
    assert rest == [ProgramChanged("O2")]


def test_job_events_name_the_program_and_its_version() -> None:
    queued = JobQueued(7, "m1", JobKind.SEND, "O1234.nc", 3, by="ann")
    started = JobStarted(7, "m1", JobKind.SEND, "O1234.nc", 3, bytes_total=1000)
    progress = JobProgress(7, "m1", JobKind.SEND, "O1234.nc", 3, bytes_done=870, bytes_total=1000)
    failed = JobFinished(
        7, "m1", JobKind.SEND, "O1234.nc", 3, outcome=JobState.FAILED, error="link lost"
    )
    assert queued.as_json() == {
        "id": 7,
        "machine": "m1",
        "event": "queued",
        "state": "queued",
        "kind": "send",
        "program": "O1234.nc",
        "version": 3,
        "by": "ann",
    }
    assert (started.as_json()["state"], started.as_json()["bytes_total"]) == ("running", 1000)
    assert (progress.as_json()["bytes_done"], progress.percent) == (870, 87)
    assert (failed.as_json()["state"], failed.as_json()["error"]) == ("failed", "link lost")
    # A stream coalesces a job's progress, never its starts and ends.
    assert progress.key == JobProgress(7, "m1", JobKind.SEND, bytes_done=900).key
    assert len({queued.key, started.key, failed.key, progress.key}) == 4


def test_progress_is_in_bytes_of_the_stored_program() -> None:
    # An XModem load counts its wire form: a 129,800-byte program with CR LF line ends is
    # 135,800 bytes on the wire. The card, the queue and the API all show the stored bytes.
    stored, wire = 129_800, 135_800
    assert stored_progress(0, wire, stored) == (0, stored)
    assert stored_progress(wire // 2, wire, stored) == (stored // 2, stored)
    assert stored_progress(wire, wire, stored) == (stored, stored)
    assert stored_progress(500, stored, stored) == (500, stored)  # a connector that counts so
    assert stored_progress(500, None, stored) == (500, stored)


def test_a_throttled_stream_sends_a_snapshot_coalesces_keeps_alive_and_resends_after_overflow() -> (
    None
):
    class Source:
        def __init__(self) -> None:
            self.pending: dict[str, Event] = {}
            self.snapshots: list[bool] = []

        async def snapshot(self, overflow: bool) -> bytes:
            self.snapshots.append(overflow)
            self.pending.clear()
            return b"snapshot\n" if not overflow else b"fresh snapshot\n"

        def take(self, event: Event) -> None:
            self.pending[event.key] = event

        async def flush(self) -> bytes:
            out = b"".join(f"{e.key}\n".encode() for e in self.pending.values())
            self.pending.clear()
            return out

    async def main() -> tuple[list[bytes], list[bool]]:
        bus = EventBus()
        bus.bind(asyncio.get_running_loop())
        source = Source()
        disconnect = asyncio.Event()

        async def disconnected() -> bool:
            return disconnect.is_set()

        got: list[bytes] = []

        async def read() -> None:
            stream = throttled_stream(
                bus, source, interval=0.2, disconnected=disconnected, keep_alive=0.5, maxsize=5
            )
            async for chunk in stream:
                got.append(chunk)

        reader = asyncio.create_task(read())
        while not got:
            await asyncio.sleep(0.01)
        for n in range(50):  # fifty progress reports of one job in one interval: one line
            bus.publish(JobProgress(1, "m1", JobKind.SEND, bytes_done=n))
            await asyncio.sleep(0)
        while len(got) < 2:
            await asyncio.sleep(0.01)
        while KEEP_ALIVE_COMMENT not in got:  # quiet: a keep-alive
            await asyncio.sleep(0.05)
        for n in range(20):  # more than the subscription holds, in one go: lost events
            bus.publish(ProgramChanged(f"O{n}"))
        while not any(b"fresh" in chunk for chunk in got):
            await asyncio.sleep(0.05)
        disconnect.set()
        await asyncio.wait({reader}, timeout=5)
        assert reader.done()
        return got, source.snapshots

    got, snapshots = asyncio.run(main())
    assert got[0] == b"snapshot\n"
    assert got[1] == b"1\n"  # the newest of the fifty, once
    assert snapshots == [False, True]
    after = next(c for c in got if b"fresh" in c)
    assert after.startswith(b"fresh snapshot\n")
