"""The MQTT publisher against the real Mosquitto: retained state per machine, changes as the
virtual control changes, job events, the health topic and its last will.

The server runs as its own process around virtual controls of this process (FleetThread); a
plain paho client listens. Every test uses its own topic prefix.
"""

from __future__ import annotations

import asyncio
import getpass
import signal
import subprocess
import uuid
from collections.abc import Iterator
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import pytest

from opendnc.server.config.shop import MqttConfig
from opendnc.server.core.components import cancel_and_wait
from opendnc.server.core.events import EventBus, JobFinished, LeaseChanged, MachineStatusChanged
from opendnc.server.core.jobwords import JobKind, JobState
from opendnc.server.core.status import MachineStatus
from opendnc.server.outputs.items import SERVER_STOPPED
from opendnc.server.outputs.mqtt import MqttPublisher
from opendnc.sim.haas.machine import Mode
from tests.peers import require_command, require_module
from tests.server.conftest import on
from tests.server.harness import Procs, auth, create_key, free_port, httpx, listening, wait_for
from tests.server.outputs_support import (
    Listener,
    ShdrReader,
    clear_retained,
    require_broker,
    start_outputs_server,
    unique_prefix,
)
from tests.server.srvx_support import PRINTS, serve_fleet
from tests.server.test_from_the_control import FleetThread

ITEM_KEYS = {
    "availability", "execution", "controller_mode", "program", "line_number", "part_count",
    "tool_number", "feed_override", "rapid_override", "spindle_override", "message", "system",
}  # fmt: skip


@pytest.fixture
def ngc(tmp_path: Path) -> Iterator[FleetThread]:
    fleet = FleetThread(tmp_path / "machines", tnc=0, haas=1)
    try:
        yield fleet
    finally:
        fleet.stop()


@pytest.fixture
def prefix(procs: Procs) -> Iterator[str]:
    """A topic prefix of this test alone on the shared broker, emptied at the end (after the
    server stopped, so that nothing comes back)."""
    require_broker()
    chosen = unique_prefix()
    yield chosen
    procs.stop_all()
    clear_retained(chosen)


def _items(message: object) -> dict[str, dict[str, object]]:
    data = message.json()  # type: ignore[attr-defined]
    items: dict[str, dict[str, object]] = data["items"]
    return items


def test_retained_state_changes_jobs_and_the_last_will(
    tmp_path: Path, ngc: FleetThread, procs: Procs, prefix: str
) -> None:
    port = start_outputs_server(
        tmp_path, procs, ngc.fleet, f'[mqtt]\nurl = "mqtt://127.0.0.1:1883"\nprefix = "{prefix}"\n'
    )
    online = "opendnc/dnc-test/online"

    # A subscriber that comes later still finds the state: it is retained.
    with Listener(prefix) as early:
        wait_for(
            "the machine available",
            lambda: (m := early.last("haas-1/availability")) and m.json()["value"] == "AVAILABLE",
            describe=lambda: procs.log("server"),
        )
    with Listener(prefix) as late:
        status = wait_for("the retained status", lambda: late.last("haas-1/status"))
        assert status.retain
        items = _items(status)
        assert set(items) == ITEM_KEYS
        for item in items.values():
            assert set(item) >= {"value", "timestamp", "quality"}
            assert (item["quality"] == "unavailable") == (item["value"] is None)
        assert items["availability"]["value"] == "AVAILABLE"
        # The virtual Haas starts in MDI (Q104 "MDI"): MTConnect's MANUAL_DATA_INPUT.
        assert items["controller_mode"]["value"] == "MANUAL_DATA_INPUT"
        assert items["feed_override"]["unit"] == "PERCENT"
        health = wait_for("the health topic", lambda: late.last(online))
        assert (health.payload, health.retain) == (b"true", True)

        # The operator turns the mode switch to MEM: the change arrives, item and status.
        sim = ngc.fleet.sims["haas-1"]
        ngc.call(lambda: sim.control.set_mode(Mode.MEM))
        changed = wait_for(
            "the mode change",
            lambda: [m for m in late.on("haas-1/controller_mode") if not m.retain],
        )
        assert changed[-1].json()["value"] == "AUTOMATIC"
        wait_for(
            "the status with the new mode",
            lambda: _items(late.last("haas-1/status"))["controller_mode"]["value"] == "AUTOMATIC",
        )
        # Report by exception: an unchanged item is not sent again every poll.
        assert not [m for m in late.on("haas-1/program") if not m.retain]

        # A job: its events go to <machine>/jobs, not retained.
        key = create_key(tmp_path / "shop.toml", f"sqlite:///{tmp_path / 'opendnc.db'}")
        with httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=30) as client:
            put = client.put(
                "/api/programs/O01000.nc", content=b"%\nO01000\nM30\n%\n", headers=auth(key)
            )
            assert put.status_code == 201, put.text
            made = client.post(
                "/api/jobs",
                json={"program": "O01000.nc", "version": 1, "machines": ["haas-1"]},
                headers=auth(key),
            )
            assert made.status_code == 201, made.text
            job_id = made.json()[0]["id"]
        done = wait_for(
            "the job's end on the jobs topic",
            lambda: [m.json() for m in late.on("haas-1/jobs") if m.json()["state"] == "done"],
        )
        assert done[0]["id"] == job_id
        assert not any(m.retain for m in late.on("haas-1/jobs"))
        # Every event names the program and its version; the first says it was queued.
        events = [m.json() for m in late.on("haas-1/jobs") if m.json()["id"] == job_id]
        assert events[0]["event"] == "queued"
        assert events[0]["state"] == "queued"
        assert events[0]["by"] == "admin"
        assert [e["event"] for e in events][-1] == "finished"
        assert "started" in [e["event"] for e in events]
        for event in events:
            assert (event["program"], event["version"], event["kind"]) == ("O01000.nc", 1, "send")
        # The status names the machine's state by the one classifier.
        assert late.last("haas-1/status").json()["state"] in ("ready", "running")  # type: ignore[union-attr]

        # The server dies without a word: the broker publishes its will.
        procs.stop("server", signal.SIGKILL)
        wait_for("the last will", lambda: late.last(online).payload == b"false")  # type: ignore[union-attr]


@on("postgresql")
def test_a_clean_stop_leaves_every_output_saying_offline(
    db_url: str, tmp_path: Path, ngc: FleetThread, procs: Procs, prefix: str
) -> None:
    """SIGTERM on PostgreSQL (a cluster of one, whose stop lets every machine go just before
    the outputs stop: the harder case; a single server's stop on SQLite is read by the
    restart test below): the broker keeps the machine unavailable, the Sparkplug host sees
    the device die before the node, an agent reads UNAVAILABLE."""
    require_module("pysparkplug")
    group = f"opendnc-test-{uuid.uuid4().hex[:10]}"
    shdr = free_port()
    with Listener(prefix) as listener, Listener(f"spBv1.0/{group}") as spb_listener:
        start_outputs_server(
            tmp_path,
            procs,
            ngc.fleet,
            f'[mqtt]\nurl = "mqtt://127.0.0.1:1883"\nprefix = "{prefix}"\n'
            f'[sparkplug]\nurl = "mqtt://127.0.0.1:1883"\ngroup = "{group}"\n'
            f'[mtconnect]\nbind = "127.0.0.1:{shdr}"\n',
            db=db_url,
        )
        topic = "opendnc/dnc-test/online"
        wait_for("online", lambda: (m := listener.last(topic)) and m.payload == b"true")
        wait_for(
            "the machine available",
            lambda: (
                (m := listener.last("haas-1/availability")) and m.json()["value"] == "AVAILABLE"
            ),
            describe=lambda: procs.log("server"),
        )
        wait_for("the device born", lambda: spb_host(spb_listener, group).of("DBIRTH"))
        wait_for("the SHDR port", listening(shdr))
        agent = ShdrReader(shdr)
        try:
            agent.until("available", lambda: agent.values.get("availability") == "AVAILABLE")
            procs.stop("server", signal.SIGTERM)
            agent.until("unavailable", lambda: agent.values["availability"] == "UNAVAILABLE")
            assert agent.conditions["system"] == {"": "UNAVAILABLE"}
            assert agent.values["message"] == "the opendnc server stopped"
        finally:
            agent.close()
        wait_for("offline", lambda: listener.last(topic).payload == b"false")  # type: ignore[union-attr]
        wait_for("the node's death", lambda: spb_host(spb_listener, group).of("NDEATH"))
        # The device dies by itself, before its node (the host's rules checked as it reads).
        assert spb_host(spb_listener, group).kinds()[-2:] == ["DDEATH:haas-1", "NDEATH"]
    # What the broker keeps after a clean stop: the machine unavailable, not AVAILABLE for good.
    with Listener(prefix) as after:
        kept = wait_for("the retained availability", lambda: after.last("haas-1/availability"))
        assert kept.retain
        assert kept.json()["value"] == "UNAVAILABLE"
        status = wait_for("the retained status", lambda: after.last("haas-1/status"))
        assert _items(status)["availability"]["value"] == "UNAVAILABLE"
        assert _items(status)["message"]["value"] == "the opendnc server stopped"
        assert status.json()["state"] == "offline"


def spb_host(listener: Listener, group: str) -> Any:
    """The tests' own Sparkplug host fed every message so far (tests/server/spb_decoder.py)."""
    from tests.server import spb_decoder

    host = spb_decoder.Host(group)
    for message in list(listener.messages):
        host.take(message.topic, message.payload)
    return host


def test_a_restart_publishes_each_machine_once_its_state_is_known(
    tmp_path: Path, ngc: FleetThread, procs: Procs, prefix: str
) -> None:
    """No UNAVAILABLE-then-AVAILABLE flip after a restart: a machine's retained state is
    published once its first status is read, not as a placeholder at connect."""
    mqtt = f'[mqtt]\nurl = "mqtt://127.0.0.1:1883"\nprefix = "{prefix}"\n'
    start_outputs_server(tmp_path, procs, ngc.fleet, mqtt)
    with Listener(prefix) as first:
        wait_for(
            "the machine available",
            lambda: (m := first.last("haas-1/availability")) and m.json()["value"] == "AVAILABLE",
            describe=lambda: procs.log("server"),
        )
        # The first run's own messages: the machine was published once, when known.
        live = [m.json()["value"] for m in first.on("haas-1/availability") if not m.retain]
        assert "UNAVAILABLE" not in live, live
    procs.stop("server", signal.SIGTERM)
    with Listener(prefix) as watcher:
        wait_for(
            "the stop's retained state",
            lambda: (
                (m := watcher.last("haas-1/availability")) and m.json()["value"] == "UNAVAILABLE"
            ),
        )
        seen = len(watcher.messages)
        start_outputs_server(tmp_path, procs, ngc.fleet, mqtt)
        wait_for(
            "the machine available again",
            lambda: watcher.last("haas-1/availability").json()["value"] == "AVAILABLE",  # type: ignore[union-attr]
            describe=lambda: procs.log("server"),
        )
        wait_for(
            "the server online", lambda: watcher.last("opendnc/dnc-test/online").payload == b"true"
        )  # type: ignore[union-attr]
        since = [m for m in watcher.messages[seen:] if m.topic.endswith("haas-1/availability")]
        assert [m.json()["value"] for m in since] == ["AVAILABLE"]
        statuses = [m for m in watcher.messages[seen:] if m.topic.endswith("haas-1/status")]
        assert statuses
        assert {_items(m)["availability"]["value"] for m in statuses} == {"AVAILABLE"}


def _private_broker(procs_dir: Path, port: int, passwords: str = "") -> subprocess.Popen[bytes]:
    mosquitto = require_command("mosquitto")
    conf = procs_dir / f"mosquitto-{port}.conf"
    # Run as root, Mosquitto would switch to its own user, who cannot read the test's folder.
    text = f"listener {port} 127.0.0.1\npersistence false\nuser {getpass.getuser()}\n"
    if passwords:
        text += f"allow_anonymous false\npassword_file {passwords}\n"
    else:
        text += "allow_anonymous true\n"
    conf.write_text(text)
    with (procs_dir / f"mosquitto-{port}.log").open("ab") as log:  # the child keeps its own fd
        return subprocess.Popen([mosquitto, "-c", str(conf)], stdout=log, stderr=subprocess.STDOUT)


def test_a_broker_outage_blocks_nothing_and_the_state_comes_back(
    tmp_path: Path, ngc: FleetThread, procs: Procs
) -> None:
    """A private Mosquitto (its own port) is stopped and started again under a running server."""
    broker_port = free_port()
    prefix = unique_prefix()
    broker = _private_broker(tmp_path, broker_port)
    try:
        wait_for("the private broker", listening(broker_port), 20)
        port = start_outputs_server(
            tmp_path,
            procs,
            ngc.fleet,
            f'[mqtt]\nurl = "mqtt://127.0.0.1:{broker_port}"\nprefix = "{prefix}"\n',
        )
        with Listener(prefix, broker_port) as listener:
            wait_for("the state", lambda: listener.last("haas-1/status"))
        broker.terminate()
        broker.wait(10)

        # With the broker away, the machine still answers and the API still serves.
        sim = ngc.fleet.sims["haas-1"]
        ngc.call(lambda: sim.control.set_mode(Mode.MEM))
        client = httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=5)
        key = create_key(tmp_path / "shop.toml", f"sqlite:///{tmp_path / 'opendnc.db'}")

        def link() -> dict[str, object]:
            got: dict[str, object] = client.get("/api/outputs", headers=auth(key)).json()["mqtt"]
            return got

        wait_for("the API to see the broker gone", lambda: link()["connected"] is False)

        def mode() -> tuple[object, object]:
            status = client.get("/api/machines/haas-1", headers=auth(key)).json()["status"]
            return status["mode"], status["native_mode"]

        # MEM in the control's words, AUTOMATIC in MTConnect's
        wait_for("the new mode through the API", lambda: mode() == ("AUTOMATIC", "MEM"))

        broker = _private_broker(tmp_path, broker_port)
        wait_for("the private broker again", listening(broker_port), 20)
        # A fresh broker (no persistence) knows nothing: the server sends the whole state.
        with Listener(prefix, broker_port) as listener:
            status = wait_for(
                "the state after the outage",
                lambda: listener.last("haas-1/status"),
                90,
                describe=lambda: procs.log("server"),
            )
            assert _items(status)["controller_mode"]["value"] == "AUTOMATIC"
            assert listener.last("opendnc/dnc-test/online").payload == b"true"  # type: ignore[union-attr]
        state = link()
        assert (state["connected"], state["connects"], state["dropped"]) == (True, 2, 0)
        client.close()
    finally:
        broker.terminate()
        broker.wait(10)


def test_a_machine_let_go_is_left_unavailable_with_the_reason(prefix: str) -> None:
    """A lease handed over (the server goes on) and a cluster's stop (the loss comes just
    before the outputs stop, not yet followed): either way the broker keeps the machine
    unavailable with the reason, not this server's last AVAILABLE."""
    config = MqttConfig(host="127.0.0.1", prefix=prefix)
    handed = "dnc-1 handed this machine to another server"

    async def until(what: str, check: Any) -> None:
        async with asyncio.timeout(20):
            while not check():
                await asyncio.sleep(0.02)

    def status_of(machine: str) -> dict[str, Any] | None:
        found = listener.last(f"{machine}/status")
        return found.json() if found is not None else None

    async def run() -> None:
        bus = EventBus()
        publisher = MqttPublisher(config, "dnc-1", ["m1", "m2"], bus)
        task = asyncio.create_task(publisher.run())
        await until("connected", publisher.synced.is_set)
        for machine in ("m1", "m2"):
            at = datetime.now(UTC)
            bus.publish(MachineStatusChanged(machine, True, MachineStatus(at, True, "READY")))
        await until("both ready", lambda: all(status_of(m) for m in ("m1", "m2")))
        assert {status_of(m)["state"] for m in ("m1", "m2")} == {"ready"}  # type: ignore[index]

        bus.publish(LeaseChanged("m1", "dnc-1", False, 0, handed))
        await until("m1 let go", lambda: status_of("m1")["state"] == "offline")  # type: ignore[index]
        bus.publish(LeaseChanged("m2", "dnc-1", False, 0, SERVER_STOPPED))
        # at once: the stop finds the loss not followed yet. Cancelled as a stop cancels
        # (again every half second): a single cancel can be swallowed by the client's wait
        # for an acknowledgement (Python 3.11's wait_for), and the task would never end.
        async with asyncio.timeout(30):
            await cancel_and_wait(task)

    with Listener(prefix) as listener:
        asyncio.run(run())
        wait_for("offline", lambda: listener.last("opendnc/dnc-1/online").payload == b"false")  # type: ignore[union-attr]
    with Listener(prefix) as after:  # what the broker keeps
        for machine, why in (("m1", handed), ("m2", SERVER_STOPPED)):
            kept = wait_for("the retained state", lambda m=machine: after.last(f"{m}/status"))  # type: ignore[misc]
            assert kept.retain
            assert kept.json()["state"] == "offline"
            assert _items(kept)["availability"]["value"] == "UNAVAILABLE"
            assert _items(kept)["message"]["value"] == why


def test_a_stop_that_cancels_again_still_leaves_everything_offline(prefix: str) -> None:
    """A stop repeats its cancel while the outputs say their last words (the components'
    cancel_and_wait every half second; here every 10 ms): the words go on within their own
    bound, so every machine is left unavailable and the health "false", not "true"."""
    # enough messages (13 a machine) for many repeated cancels to land while they go out, and
    # fewer retained topics than Mosquitto queues for a subscriber (1000)
    names = [f"m{i}" for i in range(60)]
    config = MqttConfig(host="127.0.0.1", prefix=prefix)

    async def run() -> None:
        publisher = MqttPublisher(config, "dnc-1", names, EventBus())
        for machine in names:  # known before the link is up: the whole state goes at connect
            publisher.take(
                MachineStatusChanged(machine, True, MachineStatus(datetime.now(UTC), True, "READY"))
            )
        task = asyncio.create_task(publisher.run())
        async with asyncio.timeout(20):
            await publisher.synced.wait()
            while not task.done():  # an impatient stop
                task.cancel()
                await asyncio.sleep(0.01)

    with Listener(prefix) as listener:
        asyncio.run(run())
        wait_for("offline", lambda: listener.last("opendnc/dnc-1/online").payload == b"false")  # type: ignore[union-attr]
    with Listener(prefix) as after:  # what the broker keeps
        wait_for("every machine's state", lambda: all(after.last(f"{m}/status") for m in names))
        states = {m: after.last(f"{m}/status").json()["state"] for m in names}  # type: ignore[union-attr]
        assert set(states.values()) == {"offline"}, states
        assert after.last("opendnc/dnc-1/online").payload == b"false"  # type: ignore[union-attr]


def test_the_queue_keeps_the_newest_and_counts_what_it_dropped() -> None:
    """While the broker is away only job events queue (the state is resent whole); past the
    limit the oldest go first and are counted."""
    config = MqttConfig(host="127.0.0.1", prefix="p", queue=10)

    async def run() -> MqttPublisher:
        publisher = MqttPublisher(config, "dnc", ["m1"], EventBus())
        for i in range(25):
            publisher.take(JobFinished(i, "m1", JobKind.SEND, "O1", 1, outcome=JobState.DONE))
            status = MachineStatus(at=datetime.now(UTC), available=True, program=f"O{i}")
            publisher.take(MachineStatusChanged("m1", True, status))
        return publisher

    publisher = asyncio.run(run())
    assert publisher.dropped == 15
    assert [m.topic for m in publisher.queue] == ["p/m1/jobs"] * 10
    ids = [int(m.payload.split('"id":')[1].split(",")[0]) for m in publisher.queue]
    assert ids == list(range(15, 25))
    assert publisher.tracker.snapshot("m1")["program"].value == "O24"


def test_the_broker_checks_the_configured_user_and_a_refusal_blocks_nothing(
    tmp_path: Path, ngc: FleetThread, procs: Procs
) -> None:
    passwd = require_command("mosquitto_passwd")
    passwords = tmp_path / "passwords"
    subprocess.run([passwd, "-b", "-c", str(passwords), "dnc", "s3cret"], check=True, timeout=30)
    broker_port = free_port()
    prefix = unique_prefix()
    broker = _private_broker(tmp_path, broker_port, str(passwords))
    try:
        wait_for("the private broker", listening(broker_port), 20)
        mqtt_table = (
            f'[mqtt]\nurl = "mqtt://127.0.0.1:{broker_port}"\nprefix = "{prefix}"\n'
            'username = "dnc"\npassword = "s3cret"\n'
        )
        start_outputs_server(tmp_path, procs, ngc.fleet, mqtt_table)
        with Listener(prefix, broker_port, "dnc", "s3cret") as listener:
            # The first state may be from before the machine answered: wait for it online.
            wait_for(
                "the machine available",
                lambda: (
                    (s := listener.last("haas-1/status")) is not None
                    and _items(s)["availability"]["value"] == "AVAILABLE"
                ),
            )
        procs.stop("server")

        # A wrong password: the broker refuses, the server serves its machines all the same.
        wrong = tmp_path / "wrong"
        wrong.mkdir()
        port = start_outputs_server(wrong, procs, ngc.fleet, mqtt_table.replace("s3cret", "nope"))
        key = create_key(wrong / "shop.toml", f"sqlite:///{wrong / 'opendnc.db'}")
        with httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=5) as client:
            wait_for(
                "the machine online through the API",
                lambda: client.get("/api/machines/haas-1", headers=auth(key)).json()["online"],
            )
        wait_for("the refusal in the log", lambda: "mqtt:" in procs.log("server"))
        with Listener(prefix, broker_port, "dnc", "s3cret") as listener:
            # Only the first server's retained state (its last will said false) is there.
            health = wait_for("the health", lambda: listener.last("opendnc/dnc-test/online"))
            assert health.payload == b"false"
    finally:
        broker.terminate()
        broker.wait(10)


def test_printed_lines_reach_both_outputs(tmp_path: Path, procs: Procs, prefix: str) -> None:
    """A serial Haas prints three DPRNT lines: each is a message on ``<machine>/dprnt`` and a
    ``dprnt`` MESSAGE line on the machine's SHDR port."""
    shdr_port = free_port()
    haas = FleetThread(tmp_path / "machines", tnc=0, haas=0, serial_haas=1)
    try:
        sim = haas.fleet.sims["haas-serial-1"]
        haas.call(lambda: sim.control.save_program(PRINTS))
        extra = (
            f'[mqtt]\nurl = "mqtt://127.0.0.1:1883"\nprefix = "{prefix}"\n\n'
            f'[mtconnect]\nbind = "127.0.0.1:{shdr_port}"\n'
        )
        client, _key = serve_fleet(
            tmp_path,
            haas,
            procs,
            f"sqlite:///{tmp_path / 'opendnc.db'}",
            machine_keys='dprnt = "serial"\n',
            extra=extra,
        )
        client.close()
        wait_for("the SHDR port", listening(shdr_port))
        agent = ShdrReader(shdr_port)
        try:
            with Listener(prefix) as listener:
                agent.until(
                    "the first status",
                    lambda: agent.values.get("controller_mode") == "MANUAL_DATA_INPUT",
                )
                assert agent.values["dprnt"] == "UNAVAILABLE"  # nothing printed yet
                haas.call(lambda: sim.control.start_program(500))  # cycle start
                printed = wait_for(
                    "three lines on the dprnt topic",
                    lambda: len(got := listener.on("haas-serial-1/dprnt")) == 3 and got,
                    describe=lambda: procs.log("server"),
                )
                assert [m.json()["numbers"] for m in printed] == [[0, 1.5], [1, 3.0], [2, 6.0]]
                assert not any(m.retain for m in printed)
                texts = [m.json()["line"] for m in printed]
            shdr = agent.until(
                "three dprnt lines on the SHDR port",
                lambda: len(got := [ln for ln in agent.lines if "|dprnt|" in ln][1:]) == 3 and got,
            )
            assert [ln.split("|")[3] for ln in shdr] == [" ".join(t.split()) for t in texts]
        finally:
            agent.close()
    finally:
        haas.stop()


def _certificates(folder: Path) -> tuple[Path, Path, Path, Path]:
    """A private CA, a broker certificate for 127.0.0.1 signed by it, and a second CA that
    signed nothing here: (ca, broker cert, broker key, stranger ca)."""
    openssl = require_command("openssl")

    def run(*args: str) -> None:
        subprocess.run([openssl, *args], check=True, capture_output=True, timeout=60)

    ca_key, ca, other_key, other = (folder / n for n in ("ca.key", "ca.pem", "o.key", "o.pem"))
    key, csr, cert = folder / "broker.key", folder / "broker.csr", folder / "broker.pem"
    for k, c, name in ((ca_key, ca, "test CA"), (other_key, other, "stranger CA")):
        run("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "2", "-subj", f"/CN={name}",
            "-keyout", str(k), "-out", str(c))  # fmt: skip
    run("req", "-newkey", "rsa:2048", "-nodes", "-subj", "/CN=127.0.0.1",
        "-keyout", str(key), "-out", str(csr))  # fmt: skip
    ext = folder / "san.ext"
    ext.write_text("subjectAltName = IP:127.0.0.1\n")
    run("x509", "-req", "-in", str(csr), "-CA", str(ca), "-CAkey", str(ca_key), "-CAcreateserial",
        "-days", "2", "-extfile", str(ext), "-out", str(cert))  # fmt: skip
    return ca, cert, key, other


def test_tls_to_a_broker_with_a_private_ca_and_a_stranger_ca_refused(
    tmp_path: Path, ngc: FleetThread, procs: Procs
) -> None:
    """``mqtts://`` with ``ca_file``: the state arrives over TLS; a CA that did not sign the
    broker's certificate is refused (the server serves its machines all the same)."""
    ca, cert, key, stranger = _certificates(tmp_path)
    plain_port, tls_port = free_port(), free_port()
    prefix = unique_prefix()
    mosquitto = require_command("mosquitto")
    conf = tmp_path / "tls.conf"
    # A plain listener for the test's own subscriber, a TLS one for the server.
    conf.write_text(
        f"per_listener_settings false\npersistence false\nuser {getpass.getuser()}\n"
        f"allow_anonymous true\nlistener {plain_port} 127.0.0.1\n"
        f"listener {tls_port} 127.0.0.1\ncafile {ca}\ncertfile {cert}\nkeyfile {key}\n"
    )
    with (tmp_path / "tls.log").open("ab") as log:
        broker = subprocess.Popen([mosquitto, "-c", str(conf)], stdout=log, stderr=log)
    try:
        wait_for("the TLS broker", listening(tls_port), 20)
        wait_for("its plain listener", listening(plain_port), 20)
        good = tmp_path / "good"
        good.mkdir()
        table = f'[mqtt]\nurl = "mqtts://127.0.0.1:{tls_port}"\nprefix = "{prefix}"\n'
        start_outputs_server(good, procs, ngc.fleet, table + f'ca_file = "{ca}"\n')
        with Listener(prefix, plain_port) as listener:
            wait_for(
                "the state over TLS",
                lambda: (
                    (s := listener.last("haas-1/status")) is not None
                    and _items(s)["availability"]["value"] == "AVAILABLE"
                ),
                describe=lambda: procs.log("server"),
            )
            online = wait_for("the health", lambda: listener.last("opendnc/dnc-test/online"))
            assert online.payload == b"true"
        procs.stop("server")

        bad = tmp_path / "bad"
        bad.mkdir()
        port = start_outputs_server(bad, procs, ngc.fleet, table + f'ca_file = "{stranger}"\n')
        key_text = create_key(bad / "shop.toml", f"sqlite:///{bad / 'opendnc.db'}")
        with httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=5) as client:
            wait_for(
                "the machine online through the API",
                lambda: client.get("/api/machines/haas-1", headers=auth(key_text)).json()["online"],
            )
            outputs = client.get("/api/outputs", headers=auth(key_text)).json()
            assert outputs["mqtt"]["connected"] is False, outputs
        wait_for(
            "the certificate refusal in the log",
            lambda: "certificate verify failed" in procs.log("server").lower(),
        )
    finally:
        broker.terminate()
        broker.wait(10)
