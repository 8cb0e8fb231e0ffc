"""Components around parts that have a life of their own: the open outputs (MQTT, Sparkplug B,
MTConnect) and the status timeline's recorder."""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable
from typing import Any

from sqlalchemy.exc import SQLAlchemyError

from opendnc.server.core.components import cancel_and_wait
from opendnc.server.core.events import EventBus
from opendnc.server.machines.timeline import HEARTBEAT, Timeline, running
from opendnc.server.outputs.mqtt import MqttPublisher
from opendnc.server.outputs.shdr import MtconnectOutput
from opendnc.server.outputs.sparkplug import SparkplugNode

__all__ = ["Outputs", "TimelineRecorder"]

log = logging.getLogger(__name__)


class Outputs:
    """The configured open outputs; they subscribe before the machines' first status (the
    fleet starts after them), so they miss nothing."""

    name = "outputs"
    needs = ("machines",)

    def __init__(
        self,
        mqtt: MqttPublisher | None,
        mtconnect: MtconnectOutput | None,
        sparkplug: SparkplugNode | None = None,
    ) -> None:
        self.mqtt = mqtt
        self.mtconnect = mtconnect
        self.sparkplug = sparkplug
        self._tasks: list[asyncio.Task[None]] = []

    def as_dict(self) -> dict[str, MqttPublisher | MtconnectOutput | SparkplugNode | None]:
        """The outputs by name (``None`` where not configured)."""
        return {"mqtt": self.mqtt, "sparkplug": self.sparkplug, "mtconnect": self.mtconnect}

    async def start(self) -> None:
        """Open the MTConnect ports, start the outputs' tasks (the Sparkplug node subscribes
        here, before the machines' tasks announce what this server serves)."""
        if self.sparkplug is not None:
            await self.sparkplug.start()
        if self.mqtt is not None:
            self._tasks.append(asyncio.create_task(self.mqtt.run(), name="mqtt"))
        if self.mtconnect is not None:
            await self.mtconnect.start()
            self._tasks.append(asyncio.create_task(self.mtconnect.run(), name="mtconnect"))

    async def stop(self) -> None:
        """Stop the tasks (the Sparkplug node sends its death), close the MTConnect ports."""
        tasks, self._tasks = self._tasks, []
        await cancel_and_wait(*tasks)
        if self.sparkplug is not None:
            await self.sparkplug.stop()
        if self.mtconnect is not None:
            await self.mtconnect.close()


class TimelineRecorder:
    """Records each machine's state changes for the timeline. It starts before the machines'
    tasks (it misses no first status) and stops after them, when its "no record" samples are
    written without a shop's worth of machine work queued ahead of them. At start it closes the
    record a killed server left open (docs/dashboard.md#status-timeline), and while it runs it
    notes every :data:`~opendnc.server.machines.timeline.HEARTBEAT` seconds that it is recording."""

    name = "timeline"
    needs = ("machines", "database")

    def __init__(
        self,
        timeline: Timeline,
        bus: EventBus,
        *,
        server: str,
        machines: list[str],
        held_elsewhere: Callable[[], set[str]] | None = None,
    ) -> None:
        self.timeline = timeline
        # several servers: the machines another server serves now, whose record is its own
        self.held_elsewhere = held_elsewhere
        self.bus = bus
        self.server = server
        self.machines = machines
        self.heartbeat = HEARTBEAT
        self._recording: contextlib.AbstractAsyncContextManager[Any] | None = None
        self._beating: asyncio.Task[None] | None = None

    async def start(self) -> None:
        """Close a crash's gap, subscribe and record, start the heartbeat."""

        def close_gap() -> int:
            others = self.held_elsewhere() if self.held_elsewhere is not None else set()
            mine = [m for m in self.machines if m not in others]
            return self.timeline.close_gap(self.server, mine)

        gap = await asyncio.to_thread(close_gap)
        if gap:
            log.warning("the server did not stop cleanly: no record marked for %d machines", gap)
        recording = running(self.timeline, self.bus)
        await recording.__aenter__()
        self._recording = recording
        self._beating = asyncio.create_task(self._beat(), name="timeline-heartbeat")

    async def _beat(self) -> None:
        while True:
            try:
                await asyncio.to_thread(self.timeline.beat, self.server)
            except SQLAlchemyError as exc:  # the database is away: the next beat will do
                log.info("status timeline: heartbeat not written: %s", exc)
            await asyncio.sleep(self.heartbeat)

    async def stop(self) -> None:
        """Stop the heartbeat and the recording, and write the "no record" samples."""
        beating, self._beating = self._beating, None
        if beating is not None:
            await cancel_and_wait(beating)
        recording, self._recording = self._recording, None
        if recording is not None:
            await recording.__aexit__(None, None, None)
