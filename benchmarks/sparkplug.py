"""What the Sparkplug B edge node costs: CPU per status event, and the births of a fleet.

The node folds each ``machine`` event into what it knows and, when the session sends, turns
the changed machines into DDATA (encoded by pysparkplug). This feeds it synthetic events
in-process, no broker, and reports microseconds per event (fold and encode) for polls where
nothing changed and where two metrics changed, and the time to build NBIRTH and every DBIRTH.

With ``--broker`` it also times a whole session start against the Mosquitto at
127.0.0.1:1883 (a group of its own): connect, NBIRTH and a DBIRTH per machine, until a
subscriber of the group has them all.

    .venv/bin/python benchmarks/sparkplug.py
    .venv/bin/python benchmarks/sparkplug.py --machines 500 --polls 20 --broker
"""

from __future__ import annotations

import argparse
import asyncio
import time
import uuid
from datetime import UTC, datetime, timedelta

from opendnc.server.config.shop import MqttConfig, SparkplugConfig
from opendnc.server.core.events import EventBus, LeaseChanged, MachineStatusChanged
from opendnc.server.core.status import MachineStatus
from opendnc.server.outputs.sparkplug import SparkplugNode


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


def _node(names: list[str], group: str = "bench") -> SparkplugNode:
    config = SparkplugConfig(MqttConfig(host="127.0.0.1"), group, "bench-node")
    counter = iter(range(1_000_000))
    node = SparkplugNode(config, names, EventBus(), lambda: next(counter))
    node._spb = __import__("pysparkplug")
    node.bd_seq = 0
    return node


def in_process(machines: int, polls: int) -> None:
    names = [f"m{i}" for i in range(machines)]
    node = _node(names)
    for name in names:
        node.take(LeaseChanged(name, "bench-node", True))
        node.take(_event(name, 0, change=False))
    start = time.perf_counter()
    births = node.births()
    took = time.perf_counter() - start
    size = sum(len(m.payload) for m in births)
    print(
        f"{machines} machines: NBIRTH and {len(births) - 1} DBIRTHs built in {took * 1000:.0f} ms "
        f"({size / 1024:.0f} KiB)"
    )
    for label, change in (("unchanged", False), ("2 metrics changed", True)):
        events = [_event(n, p, change) for p in range(1, polls + 1) for n in names]
        start = time.perf_counter()
        sent = 0
        for index, event in enumerate(events):
            node.take(event)
            if index % machines == machines - 1:  # one send per poll of the whole fleet
                sent += len(node.changes())
        us = (time.perf_counter() - start) / len(events) * 1e6
        print(
            f"{machines} machines, {label}: {us:.1f} us/event, {sent} DDATA; at one poll a "
            f"second {machines * us / 1e4:.1f} % of a core"
        )


async def session(machines: int) -> None:
    import paho.mqtt.client as mqtt

    group = f"opendnc-bench-{uuid.uuid4().hex[:8]}"
    names = [f"m{i}" for i in range(machines)]
    node = _node(names, group)
    node._sub_cm = node.bus.subscribe(maxsize=100_000)
    node._sub = node._sub_cm.__enter__()
    for name in names:
        node.take(LeaseChanged(name, "bench-node", True))
        node.take(_event(name, 0, change=False))
    got: list[str] = []
    if hasattr(mqtt, "CallbackAPIVersion"):  # paho 2 wants one; 1.x (with pysparkplug) none
        listener = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2)
    else:
        listener = mqtt.Client()
    listener.on_message = lambda _c, _u, message: got.append(message.topic)
    listener.connect("127.0.0.1", 1883)
    listener.subscribe(f"spBv1.0/{group}/#", 0)
    listener.loop_start()
    time.sleep(0.5)  # the subscription is in place (a benchmark, not a test)
    start = time.perf_counter()
    task = asyncio.create_task(node.run())
    while len(got) < machines + 1:
        await asyncio.sleep(0.01)
    took = time.perf_counter() - start
    task.cancel()
    await asyncio.gather(task, return_exceptions=True)
    listener.loop_stop()
    listener.disconnect()
    print(f"a session of {machines} machines: connected and born in {took:.2f} s")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--machines", type=int, default=500)
    parser.add_argument("--polls", type=int, default=20)
    parser.add_argument("--broker", action="store_true", help="also time a session's births")
    args = parser.parse_args()
    in_process(args.machines, args.polls)
    if args.broker:
        asyncio.run(session(args.machines))
