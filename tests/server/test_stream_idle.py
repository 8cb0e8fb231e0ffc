"""An idle event stream sleeps until its next heartbeat, and ends after its idle time
(docs/server.md#bounded-clients): no wake-up per flush interval, which is what made 1,200
idle streams cost most of the server's CPU."""

from __future__ import annotations

import asyncio

from opendnc.server.core.events import Event, EventBus, ProgramChanged
from opendnc.server.http.streams import KEEP_ALIVE_COMMENT, throttled_stream


class Quiet:
    """A source with nothing to say but what the events bring."""

    def __init__(self) -> None:
        self.names: list[str] = []

    async def snapshot(self, overflow: bool) -> bytes:
        return b"snapshot\n"

    def take(self, event: Event) -> None:
        self.names.append(event.key)

    async def flush(self) -> bytes:
        out = b"".join(f"{n}\n".encode() for n in self.names)
        self.names.clear()
        return out


def test_an_idle_stream_wakes_only_for_its_heartbeats_and_ends_after_its_idle_time() -> None:
    async def main() -> tuple[list[bytes], int, float]:
        bus = EventBus()
        bus.bind(asyncio.get_running_loop())
        asked = 0

        async def disconnected() -> bool:
            nonlocal asked
            asked += 1  # once per wake-up of the stream
            return False

        loop = asyncio.get_running_loop()
        started = loop.time()
        got = []
        stream = throttled_stream(
            bus, Quiet(), interval=0.02, disconnected=disconnected, keep_alive=0.25, idle=1.0
        )
        async for chunk in stream:
            got.append(chunk)
            if len(got) == 2:
                bus.publish(ProgramChanged("O1"))  # news: the idle time starts again
        return got, asked, loop.time() - started

    got, asked, took = asyncio.run(main())
    assert got[0] == b"snapshot\n"
    assert got[2] == b"O1\n"
    assert got[1] == KEEP_ALIVE_COMMENT
    assert set(got[3:]) == {KEEP_ALIVE_COMMENT}
    assert 3 <= len(got[3:]) <= 4  # a heartbeat every 0.25 s of the last second
    # it ended by itself, a second after its last news (which came with the first
    # heartbeat, itself up to a quarter of one early: streams opened together spread out)
    assert 1.1 <= took <= 3.0
    # a wake-up per heartbeat and per event (about ten), not one per 0.02 s interval (~60)
    assert asked <= 15
