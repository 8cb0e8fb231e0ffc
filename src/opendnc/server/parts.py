"""Components around parts that have a life of their own: the open outputs (MQTT, MTConnect)
and the status timeline's recorder."""

from __future__ import annotations

import asyncio
import contextlib
from typing import Any

from opendnc.server.components import cancel_and_wait
from opendnc.server.events import EventBus
from opendnc.server.mqtt import MqttPublisher
from opendnc.server.shdr import MtconnectOutput
from opendnc.server.web.timeline import Timeline, running

__all__ = ["Outputs", "TimelineRecorder"]


class Outputs:
    """The configured open outputs; they subscribe before the machines' first status (the
    fleet starts after them), so they miss nothing."""

    name = "outputs"
    needs = ("machines",)

    def __init__(self, mqtt: MqttPublisher | None, mtconnect: MtconnectOutput | None) -> None:
        self.mqtt = mqtt
        self.mtconnect = mtconnect
        self._tasks: list[asyncio.Task[None]] = []

    def as_dict(self) -> dict[str, MqttPublisher | MtconnectOutput | None]:
        """The outputs by name (``None`` where not configured)."""
        return {"mqtt": self.mqtt, "mtconnect": self.mtconnect}

    async def start(self) -> None:
        """Open the MTConnect ports, start both outputs' tasks."""
        if self.mqtt is not None:
            self._tasks.append(asyncio.create_task(self.mqtt.run(), name="mqtt"))
        if self.mtconnect is not None:
            await self.mtconnect.start()
            self._tasks.append(asyncio.create_task(self.mtconnect.run(), name="mtconnect"))

    async def stop(self) -> None:
        """Stop the tasks, close the MTConnect ports."""
        tasks, self._tasks = self._tasks, []
        await cancel_and_wait(*tasks)
        if self.mtconnect is not None:
            await self.mtconnect.close()


class TimelineRecorder:
    """Records each machine's state changes for the timeline; starts after the machines and
    stops first, so its "no record" samples mark the server's stop."""

    name = "timeline"
    needs = ("fleet",)

    def __init__(self, timeline: Timeline, bus: EventBus) -> None:
        self.timeline = timeline
        self.bus = bus
        self._recording: contextlib.AbstractAsyncContextManager[Any] | None = None

    async def start(self) -> None:
        """Subscribe and record."""
        recording = running(self.timeline, self.bus)
        await recording.__aenter__()
        self._recording = recording

    async def stop(self) -> None:
        """Stop recording and write the "no record" samples."""
        recording, self._recording = self._recording, None
        if recording is not None:
            await recording.__aexit__(None, None, None)
