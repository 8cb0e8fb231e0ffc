"""The Sparkplug B edge node against the real Mosquitto, read by the tests' own host
application (tests/server/spb_decoder.py: a decoder of our own, not pysparkplug).

Births, data by exception, the rebirth command, deaths, ``seq`` and ``bdSeq`` across a clean
stop, a SIGKILL and a restart, the primary host's STATE, and a machine moving from one server
to another (DDEATH from one node, DBIRTH from the other).
"""

from __future__ import annotations

import asyncio
import signal
import threading
import time
import uuid
from dataclasses import replace
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import pytest

from tests.peers import require_module

require_module("pysparkplug")
require_module("google.protobuf")

from opendnc.server.config.shop import parse_config  # noqa: E402
from opendnc.server.core.events import EventBus, LeaseChanged, MachineStatusChanged  # noqa: E402
from opendnc.server.core.status import MachineStatus  # noqa: E402
from opendnc.server.outputs.sparkplug import REBIRTH, SparkplugNode  # noqa: E402
from opendnc.server.outputs.sparkplug_store import next_bd_seq  # noqa: E402
from opendnc.server.store.db import make_engine, make_sessions, migrate  # noqa: E402
from opendnc.sim.haas.machine import Mode  # noqa: E402
from tests.server import spb_decoder as spb  # noqa: E402
from tests.server.harness import Procs, auth, create_key, httpx, wait_for  # noqa: E402
from tests.server.outputs_support import (  # noqa: E402
    Listener,
    clear_retained,
    require_broker,
    start_outputs_server,
)
from tests.server.test_from_the_control import FleetThread  # noqa: E402


@pytest.fixture
def group() -> str:
    """A Sparkplug group of this test alone on the shared broker."""
    require_broker()
    return f"opendnc-test-{uuid.uuid4().hex[:10]}"


def host_of(listener: Listener, group: str) -> spb.Host:
    """The test's host application fed every message so far (it raises on a broken rule)."""
    host = spb.Host(group)
    for message in list(listener.messages):
        host.take(message.topic, message.payload)
    return host


def bd_seq_of(host: spb.Host, node: str, kind: str = "NBIRTH", index: int = -1) -> int:
    value: int = host.of(kind, node=node)[index].payload.by_name()["bdSeq"].value
    return value


class NodeThread:
    """A :class:`SparkplugNode` on its own event loop, fed bus events from the test."""

    def __init__(self, tmp_path: Path, toml: str, machines: list[str]) -> None:
        config = parse_config(toml, base=tmp_path)
        assert config.sparkplug is not None
        engine = make_engine(f"sqlite:///{tmp_path / 'spb.db'}")
        migrate(engine)
        self.engine = engine
        sessions = make_sessions(engine)
        spc = replace(config.sparkplug, node=config.sparkplug.node or config.server.name)
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()
        self.bus = EventBus()
        self.bus.bind(self.loop)
        self.node = SparkplugNode(
            spc, machines, self.bus, lambda: next_bd_seq(sessions, spc.group, spc.node)
        )
        self._run(self.node.start())

    def _run(self, coroutine: Any) -> Any:
        return asyncio.run_coroutine_threadsafe(coroutine, self.loop).result(30)

    def publish(self, event: object) -> None:
        self.bus.publish(event)  # type: ignore[arg-type]

    def stop(self) -> None:
        self._run(self.node.stop())
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(10)
        self.loop.close()
        self.engine.dispose()


def toml(group: str, extra: str = "") -> str:
    return (
        '[server]\nname = "dnc-a"\n[library]\npath = "lib"\n'
        '[[machines]]\nname = "mill-1"\nkind = "lsv2"\nhost = "127.0.0.1"\n'
        '[[machines]]\nname = "mill-2"\nkind = "lsv2"\nhost = "127.0.0.1"\n'
        f'[sparkplug]\nurl = "mqtt://127.0.0.1:1883"\ngroup = "{group}"\n{extra}'
    )


def status(machine: str, **kw: Any) -> MachineStatusChanged:
    fields: dict[str, Any] = {"at": datetime.now(UTC), "available": True, "execution": "READY"}
    fields.update(kw)
    return MachineStatusChanged(machine, True, MachineStatus(**fields))


def test_births_data_rebirth_deaths_and_bd_seq_across_restarts(tmp_path: Path, group: str) -> None:
    with Listener(f"spBv1.0/{group}") as listener:
        edge = NodeThread(tmp_path, toml(group), ["mill-1", "mill-2"])
        try:
            wait_for("NBIRTH", lambda: host_of(listener, group).of("NBIRTH"))
            first = bd_seq_of(host_of(listener, group), "dnc-a")

            edge.publish(LeaseChanged("mill-1", "dnc-a", True))
            edge.publish(status("mill-1", program="A.H", part_count=1))
            wait_for("DBIRTH", lambda: host_of(listener, group).of("DBIRTH", device="mill-1"))
            edge.publish(status("mill-1", program="A.H", part_count=2))
            wait_for("DDATA", lambda: host_of(listener, group).of("DDATA", device="mill-1"))
            edge.publish(status("mill-1", program="A.H", part_count=2))  # no change: nothing
            edge.publish(status("mill-1", program="B.H", part_count=2))
            wait_for(
                "the program change",
                lambda: (
                    host_of(listener, group).device("dnc-a", "mill-1").values["program"]  # type: ignore[union-attr]
                    == "B.H"
                ),
            )
            host = host_of(listener, group)
            data = host.of("DDATA", device="mill-1")
            # By exception, by alias: only what changed (changes between two sends coalesce).
            assert [[m.name for m in d.payload.metrics] for d in data] == [[None], [None]]
            assert host.device("dnc-a", "mill-1").values["part_count"] == 2  # type: ignore[union-attr]

            # The host asks for a rebirth: NBIRTH (same session, same bdSeq) and the devices.
            listener.client.publish(
                f"spBv1.0/{group}/NCMD/dnc-a",
                spb.encode_command({REBIRTH: True}, int(time.time() * 1000)),
                qos=1,
            )
            wait_for("the rebirth", lambda: len(host_of(listener, group).of("NBIRTH")) == 2)
            wait_for("the DBIRTH again", lambda: len(host_of(listener, group).of("DBIRTH")) == 2)
            assert bd_seq_of(host_of(listener, group), "dnc-a") == first

            edge.publish(LeaseChanged("mill-1", "dnc-a", False))
            wait_for("DDEATH", lambda: host_of(listener, group).of("DDEATH", device="mill-1"))
        finally:
            edge.stop()
        # A clean stop says NDEATH itself, with the session's bdSeq.
        wait_for("NDEATH", lambda: host_of(listener, group).of("NDEATH"))
        assert bd_seq_of(host_of(listener, group), "dnc-a", "NDEATH") == first

        # Started again: the next bdSeq, kept in the database.
        edge = NodeThread(tmp_path, toml(group), ["mill-1", "mill-2"])
        try:
            wait_for("NBIRTH again", lambda: len(host_of(listener, group).of("NBIRTH")) == 3)
            assert bd_seq_of(host_of(listener, group), "dnc-a") == (first + 1) % 256
        finally:
            edge.stop()
        # the stop's NDEATH reaches the listener through the broker a moment later
        wait_for("the last NDEATH", lambda: len(host_of(listener, group).of("NDEATH")) == 2)
        host = host_of(listener, group)
        assert host.kinds() == [
            "NBIRTH", "DBIRTH:mill-1", "DDATA:mill-1", "DDATA:mill-1", "NCMD", "NBIRTH",
            "DBIRTH:mill-1", "DDEATH:mill-1", "NDEATH", "NBIRTH", "NDEATH",
        ]  # fmt: skip


def test_waits_for_the_primary_host_and_leaves_when_it_goes(tmp_path: Path, group: str) -> None:
    host_id = f"scada-{uuid.uuid4().hex[:8]}"
    state_topic = f"spBv1.0/STATE/{host_id}"
    try:
        with Listener(f"spBv1.0/{group}") as listener:
            stamp = int(time.time() * 1000)
            listener.client.publish(
                state_topic, spb.state_payload(False, stamp), qos=1, retain=True
            ).wait_for_publish(10)
            edge = NodeThread(tmp_path, toml(group, f'primary_host = "{host_id}"\n'), ["mill-1"])
            try:
                edge.publish(LeaseChanged("mill-1", "dnc-a", True))
                edge.publish(status("mill-1"))
                wait_for(
                    "the node to read the host's STATE", lambda: edge.node._host_stamp == stamp
                )
                # A marker through the same broker: whatever the node sent before it has come.
                listener.client.publish(f"spBv1.0/{group}/marker", b"1", qos=1)
                wait_for("the marker", lambda: listener.on("marker"))
                assert edge.node.connected
                assert not host_of(listener, group).of("NBIRTH"), "born while the host is away"

                listener.client.publish(
                    state_topic, spb.state_payload(True, stamp + 1), qos=1, retain=True
                )
                wait_for("NBIRTH", lambda: host_of(listener, group).of("NBIRTH"))
                wait_for("DBIRTH", lambda: host_of(listener, group).of("DBIRTH"))
                first = bd_seq_of(host_of(listener, group), "dnc-a")

                # The host goes offline: the node dies and connects again, waiting.
                listener.client.publish(
                    state_topic, spb.state_payload(False, stamp + 2), qos=1, retain=True
                )
                wait_for("NDEATH", lambda: host_of(listener, group).of("NDEATH"))
                assert bd_seq_of(host_of(listener, group), "dnc-a", "NDEATH") == first
                wait_for("a new session", lambda: edge.node.connects == 2)
                listener.client.publish(
                    state_topic, spb.state_payload(True, stamp + 3), qos=1, retain=True
                )
                wait_for("NBIRTH again", lambda: len(host_of(listener, group).of("NBIRTH")) == 2)
                assert bd_seq_of(host_of(listener, group), "dnc-a") == (first + 1) % 256
                wait_for("DBIRTH again", lambda: len(host_of(listener, group).of("DBIRTH")) == 2)
            finally:
                edge.stop()
    finally:
        clear_retained(state_topic)


def test_a_served_machine_through_sigkill_and_restart(
    tmp_path: Path, procs: Procs, group: str
) -> None:
    fleet = FleetThread(tmp_path / "machines", tnc=0, haas=1)
    try:
        extra = f'[sparkplug]\nurl = "mqtt://127.0.0.1:1883"\ngroup = "{group}"\n'
        with Listener(f"spBv1.0/{group}") as listener:
            port = start_outputs_server(tmp_path, procs, fleet.fleet, extra, name="dnc-b")
            wait_for(
                "the machine born with its status",
                lambda: host_of(listener, group).of("DBIRTH", device="haas-1"),
                describe=lambda: procs.log("server"),
            )
            key = create_key(tmp_path / "shop.toml", f"sqlite:///{tmp_path / 'opendnc.db'}")
            with httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=30) as client:
                said = client.get("/api/outputs", headers=auth(key)).json()["sparkplug"]
            assert said["connected"] is True
            assert (said["group"], said["node"], said["devices"]) == (group, "dnc-b", ["haas-1"])
            assert said["bd_seq"] == bd_seq_of(host_of(listener, group), "dnc-b")
            device = host_of(listener, group).device("dnc-b", "haas-1")
            assert device is not None
            assert device.values["availability"] == "AVAILABLE"
            # The virtual Haas starts in MDI (Q104 "MDI"): MTConnect's MANUAL_DATA_INPUT.
            assert device.values["controller_mode"] == "MANUAL_DATA_INPUT"
            first = bd_seq_of(host_of(listener, group), "dnc-b")

            sim = fleet.fleet.sims["haas-1"]
            fleet.call(lambda: sim.control.set_mode(Mode.MEM))
            wait_for(
                "the mode change as DDATA",
                lambda: (
                    host_of(listener, group)
                    .device("dnc-b", "haas-1")
                    .values[  # type: ignore[union-attr]
                        "controller_mode"
                    ]
                    == "AUTOMATIC"
                ),
            )
            assert host_of(listener, group).of("DDATA", device="haas-1")

            # The control stops answering (its MDC port closes under the link): the node says
            # the device is dead, not a DDATA "unavailable" (Sparkplug 3.0, 5.7), and bears it
            # again once the control answers on the same port.
            assert sim.mdc is not None
            mdc = sim.mdc
            fleet.run(mdc.close)
            wait_for(
                "the device's death",
                lambda: host_of(listener, group).of("DDEATH", device="haas-1"),
                describe=lambda: host_of(listener, group).kinds(),
            )
            assert not host_of(listener, group).device("dnc-b", "haas-1").alive  # type: ignore[union-attr]
            fleet.run(mdc.start)
            wait_for(
                "born again when it answers",
                lambda: len(host_of(listener, group).of("DBIRTH", device="haas-1")) == 2,
                describe=lambda: host_of(listener, group).kinds(),
            )
            host = host_of(listener, group)
            assert host.kinds()[-2:] == ["DDEATH:haas-1", "DBIRTH:haas-1"]
            assert host.device("dnc-b", "haas-1").values["availability"] == "AVAILABLE"  # type: ignore[union-attr]

            # Killed: the broker sends the will, the NDEATH of that session.
            procs.stop("server", signal.SIGKILL)
            wait_for("the will", lambda: host_of(listener, group).of("NDEATH"))
            assert bd_seq_of(host_of(listener, group), "dnc-b", "NDEATH") == first
            assert not host_of(listener, group).nodes["dnc-b"].alive

            start_outputs_server(tmp_path, procs, fleet.fleet, extra, name="dnc-b")
            wait_for(
                "born again",
                lambda: len(host_of(listener, group).of("DBIRTH", device="haas-1")) == 3,
                describe=lambda: procs.log("server"),
            )
            assert bd_seq_of(host_of(listener, group), "dnc-b") == (first + 1) % 256
            assert (
                host_of(listener, group)
                .device("dnc-b", "haas-1")
                .values[  # type: ignore[union-attr]
                    "controller_mode"
                ]
                == "AUTOMATIC"
            )
    finally:
        procs.stop_all()
        fleet.stop()


def test_a_machine_moves_between_servers(tmp_path: Path, group: str) -> None:
    """A machine's lease moves: its old server stops serving it and says so, the new one
    says so and serves it, as the cluster component does (``LeaseChanged`` around
    ``Fleet.release`` and ``Fleet.serve``, server/cluster/cluster.py)."""
    from tests.server.inprocess_app import running

    machines: list[dict[str, object]] = [{"name": "m1", "kind": "lsv2", "host": "127.0.0.1"}]

    def extra(name: str) -> str:
        return (
            f'[server]\nname = "{name}"\n'
            f'[sparkplug]\nurl = "mqtt://127.0.0.1:1883"\ngroup = "{group}"\n'
        )

    def on_loop(app: Any, coroutine: Any) -> None:
        loop = app.server.machines._loop
        asyncio.run_coroutine_threadsafe(coroutine, loop).result(30)

    def lose(app: Any, machine: str) -> None:
        async def go() -> None:
            await app.server.fleet.release(machine)
            app.server.bus.publish(LeaseChanged(machine, app.server.config.server.name, False))

        on_loop(app, go())

    def gain(app: Any, machine: str) -> None:
        async def go() -> None:
            app.server.bus.publish(LeaseChanged(machine, app.server.config.server.name, True))
            app.server.fleet.serve(machine)

        on_loop(app, go())

    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    with (
        Listener(f"spBv1.0/{group}") as listener,
        running(tmp_path / "a", machines, extra=extra("dnc-a")) as a,
    ):
        wait_for("m1 born on dnc-a", lambda: host_of(listener, group).of("DBIRTH", "dnc-a"))
        with running(tmp_path / "b", machines, extra=extra("dnc-b")) as b:
            wait_for("m1 born on dnc-b", lambda: host_of(listener, group).of("DBIRTH", "dnc-b"))
            lose(b, "m1")  # one server at a time from here
            wait_for("dnc-b lets go", lambda: host_of(listener, group).of("DDEATH", "dnc-b"))

            lose(a, "m1")
            gain(b, "m1")
            wait_for(
                "m1 born again on dnc-b",
                lambda: len(host_of(listener, group).of("DBIRTH", "dnc-b")) == 2,
            )
            # Each server publishes on its own connection: the broker may pass dnc-b's birth
            # before dnc-a's death (seen under load in CI). A host keeps each node's devices
            # apart, so what counts is the state both leave it in.
            wait_for("dnc-a lets go", lambda: host_of(listener, group).of("DDEATH", "dnc-a"))
            host = host_of(listener, group)
            assert host.device("dnc-b", "m1").alive  # type: ignore[union-attr]
            assert not host.device("dnc-a", "m1").alive  # type: ignore[union-attr]
