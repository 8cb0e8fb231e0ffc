"""The dashboard streams' heartbeat: a named event the page's script can hear (a comment it
cannot), with the server's time and the shop's zone label, at least every 2 s."""

from __future__ import annotations

import asyncio
import json
from datetime import UTC, datetime
from zoneinfo import ZoneInfo

from tests.peers import require_module

require_module("jinja2")

from opendnc.server.core.events import Event  # noqa: E402
from opendnc.server.web.heartbeat import HEARTBEAT, Heartbeat, heartbeat_event  # noqa: E402

BERLIN = ZoneInfo("Europe/Berlin")


class _Quiet:
    """A source with nothing to say."""

    async def snapshot(self, overflow: bool) -> bytes:
        return b""

    def take(self, event: Event) -> None:
        pass

    async def flush(self) -> bytes:
        return b""


def _data(message: bytes) -> dict[str, str]:
    lines = message.decode().splitlines()
    assert lines[0] == "event: heartbeat"
    found: dict[str, str] = json.loads(lines[1].removeprefix("data: "))
    return found


def test_the_heartbeat_names_the_shops_zone_as_its_clock_does() -> None:
    winter = _data(heartbeat_event(BERLIN, datetime(2026, 1, 5, 12, tzinfo=UTC)))
    summer = _data(heartbeat_event(BERLIN, datetime(2026, 7, 5, 12, tzinfo=UTC)))
    assert winter == {"at": "2026-01-05T12:00:00+00:00", "zone": "CET"}
    assert summer["zone"] == "CEST"


def test_a_quiet_stream_beats_every_two_seconds() -> None:
    now = [100.0]
    beat = Heartbeat(_Quiet(), BERLIN, clock=lambda: now[0])

    async def run() -> list[bytes]:
        # the stream sends the snapshot with the first flush (at once: the zone is known)
        out = [await beat.snapshot(False) + await beat.flush()]
        for _ in range(10):  # the stream's loop flushes every 0.5 s
            now[0] += 0.5
            out.append(await beat.flush())
        return out

    sent = asyncio.run(run())
    assert sent[0].startswith(b"event: heartbeat\n")
    beats = [i for i, b in enumerate(sent) if b]
    assert beats == [0, 4, 8]  # 0 s, 2 s, 4 s
    assert HEARTBEAT == 2.0
