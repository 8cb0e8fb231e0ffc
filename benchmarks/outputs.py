"""What the open outputs cost the server per status poll: CPU per ``machine`` event.

The supervisor publishes one ``machine`` event per machine and poll (500 machines polled
every second: 500 events a second). This feeds the MQTT publisher and the MTConnect output
the same synthetic events in-process, with no broker and no agent connected (queue and line
building only, the part that runs on the server's event loop), and reports microseconds per
event for polls where nothing changed (the common case) and where two items changed.

With ``--broker`` it also times the whole state a (re)connection sends, to the Mosquitto at
127.0.0.1:1883 under a prefix of its own (deleted afterwards): one retained status and 12
retained items per machine, QoS 1, until the broker has acknowledged them all; and a clean
stop: from the cancel to the end of the publisher, and how many machines the broker then
keeps as offline (a stop has 2 s with the broker: docs/server.md#mqtt).

    .venv/bin/python benchmarks/outputs.py
    .venv/bin/python benchmarks/outputs.py --machines 500 --polls 20 --broker
"""

from __future__ import annotations

import argparse
import asyncio
import time
from datetime import UTC, datetime, timedelta
from typing import Any

from opendnc.server.config.shop import MqttConfig, MtconnectConfig
from opendnc.server.core.components import cancel_and_wait
from opendnc.server.core.events import EventBus, MachineStatusChanged
from opendnc.server.core.status import MachineStatus
from opendnc.server.outputs.mqtt import MqttPublisher
from opendnc.server.outputs.shdr import MtconnectOutput


def _event(name: str, poll: int, change: bool) -> MachineStatusChanged:
    at = datetime(2026, 1, 1, tzinfo=UTC) + timedelta(seconds=poll)
    status = MachineStatus(
        at=at,
        available=True,
        execution=("ACTIVE" if poll % 2 else "READY") if change else "ACTIVE",
        mode="AUTOMATIC",
        program="O1000",
        line=poll if change else 12,
        part_count=7,
        tool=3,
        overrides={"feed": 100.0, "spindle": 100.0, "rapid": 50.0},
    )
    return MachineStatusChanged(name, True, status)


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
        shdr_us = _measure(shdr.take, names, polls, change)
        per_second = machines * (mqtt_us + shdr_us) / 1e6
        print(
            f"{machines} machines, {label}: MQTT {mqtt_us:.1f} us/event, "
            f"SHDR {shdr_us:.1f} us/event; at one poll a second both cost "
            f"{per_second * 100:.1f} % of a core"
        )


async def whole_state(machines: int) -> None:
    import uuid

    import aiomqtt

    prefix = f"opendnc-bench/{uuid.uuid4().hex[:8]}"
    names = [f"m{i}" for i in range(machines)]
    config = MqttConfig(host="127.0.0.1", prefix=prefix)
    publisher = MqttPublisher(config, "bench", names, EventBus())
    for name in names:  # every machine read once: only a known machine's state is published
        publisher.take(_event(name, 0, change=False))
    topics = [m.topic for m in publisher._whole_state()] + [publisher.health_topic]
    start = time.perf_counter()
    task = asyncio.create_task(publisher.run())
    # Every message acknowledged by the broker (QoS 1): the retained state is in place.
    await publisher.synced.wait()
    elapsed = time.perf_counter() - start
    task.cancel()
    await asyncio.gather(task, return_exceptions=True)
    async with aiomqtt.Client("127.0.0.1", 1883) as cleaner:
        for topic in topics:  # an empty retained message deletes the retained one
            await cleaner.publish(topic, b"", qos=1, retain=True)
    print(
        f"whole state of {machines} machines ({len(topics)} retained messages, QoS 1, "
        f"acknowledged one by one): {elapsed:.2f} s, {len(topics) / elapsed:.0f} messages/s"
    )


async def clean_stop(machines: int) -> None:
    import uuid

    import aiomqtt

    prefix = f"opendnc-bench/{uuid.uuid4().hex[:8]}"
    names = [f"m{i}" for i in range(machines)]
    publisher = MqttPublisher(
        MqttConfig(host="127.0.0.1", prefix=prefix), "bench", names, EventBus()
    )
    for name in names:
        publisher.take(_event(name, 0, change=False))
    topics = [m.topic for m in publisher._whole_state()] + [publisher.health_topic]
    task = asyncio.create_task(publisher.run())
    await publisher.synced.wait()
    start = time.perf_counter()
    await cancel_and_wait(task)  # as the server's outputs component stops it
    elapsed = time.perf_counter() - start
    offline, health = 0, b""
    async with aiomqtt.Client("127.0.0.1", 1883) as reader:
        await reader.subscribe(f"{prefix}/+/status", qos=1)
        await reader.subscribe(publisher.health_topic, qos=1)
        try:
            async with asyncio.timeout(2):
                async for message in reader.messages:  # the retained ones, then silence
                    payload = bytes(message.payload)  # type: ignore[arg-type]
                    if str(message.topic) == publisher.health_topic:
                        health = payload
                    else:
                        offline += b'"state":"offline"' in payload
        except TimeoutError:
            pass
        for topic in topics:
            await reader.publish(topic, b"", qos=1, retain=True)
    print(
        f"clean stop of {machines} machines: {elapsed:.2f} s, {offline} of {machines} "
        f"kept offline by the broker, online {health.decode() or '(none)'}"
    )


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--machines", type=int, default=500)
    parser.add_argument("--polls", type=int, default=20)
    parser.add_argument("--broker", action="store_true", help="also time the whole state")
    args = parser.parse_args()
    asyncio.run(main(args.machines, args.polls))
    if args.broker:
        asyncio.run(whole_state(args.machines))
        asyncio.run(clean_stop(args.machines))
