"""What the open outputs cost the server per status poll: CPU per ``machine`` event.

The supervisor publishes one ``machine`` event per machine and poll (500 machines polled
every second: 500 events a second). This feeds the MQTT publisher and the MTConnect output
the same synthetic events in-process, with no broker and no agent connected (queue and line
building only, the part that runs on the server's event loop), and reports microseconds per
event for polls where nothing changed (the common case) and where two items changed.

    .venv/bin/python benchmarks/outputs.py
    .venv/bin/python benchmarks/outputs.py --machines 500 --polls 20
"""

from __future__ import annotations

import argparse
import asyncio
import time
from datetime import UTC, datetime, timedelta
from typing import Any

from opendnc.server.config import MqttConfig, MtconnectConfig
from opendnc.server.events import Event, EventBus
from opendnc.server.mqtt import MqttPublisher
from opendnc.server.shdr import MtconnectOutput


def _event(name: str, poll: int, change: bool) -> Event:
    at = datetime(2026, 1, 1, tzinfo=UTC) + timedelta(seconds=poll)
    status: dict[str, Any] = {
        "at": at.isoformat(),
        "available": True,
        "execution": ("ACTIVE" if poll % 2 else "READY") if change else "ACTIVE",
        "mode": "AUTOMATIC",
        "program": "O1000",
        "line": poll if change else 12,
        "part_count": 7,
        "tool": 3,
        "overrides": {"feed": 100.0, "spindle": 100.0, "rapid": 50.0},
        "errors": [],
        "message": "",
    }
    return Event("machine", name, {"name": name, "online": True, "status": status})


def _measure(take: Any, names: list[str], polls: int, change: bool) -> float:
    events = [_event(n, p, change) for p in range(polls) for n in names]
    start = time.perf_counter()
    for event in events:
        take(event)
    return (time.perf_counter() - start) / len(events) * 1e6


async def main(machines: int, polls: int) -> None:
    names = [f"m{i}" for i in range(machines)]
    bus = EventBus()
    publisher = MqttPublisher(MqttConfig(host="127.0.0.1", queue=1_000_000), "dnc", names, bus)
    publisher.connected = True  # queue as when the broker is there (nothing is sent here)
    shdr = MtconnectOutput(MtconnectConfig("127.0.0.1", dict.fromkeys(names, 0)), names, bus)
    for label, change in (("unchanged", False), ("2 items changed", True)):
        publisher.queue.clear()
        mqtt_us = _measure(publisher.take, names, polls, change)
        shdr_us = _measure(lambda e: shdr.take(e.key, e.data), names, polls, change)
        per_second = machines * (mqtt_us + shdr_us) / 1e6
        print(
            f"{machines} machines, {label}: MQTT {mqtt_us:.1f} us/event, "
            f"SHDR {shdr_us:.1f} us/event; at one poll a second both cost "
            f"{per_second * 100:.1f} % of a core"
        )


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--machines", type=int, default=500)
    parser.add_argument("--polls", type=int, default=20)
    args = parser.parse_args()
    asyncio.run(main(args.machines, args.polls))
