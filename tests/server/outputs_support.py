"""What the output tests share: an MQTT listener on the real broker, a strict SHDR reader
written from the MTConnect facts (no MTConnect agent installs here), a server around a fleet."""

from __future__ import annotations

import json
import re
import socket
import threading
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

from opendnc.sim.fleet import server_config
from tests.peers import missing_peer, require_module
from tests.server.harness import Procs, wait_for

mqtt = require_module("paho.mqtt.client")

BROKER = ("127.0.0.1", 1883)

# MTConnect's vocabulary, from the standard (part 2) as docs/server.md#mtconnect cites it.
AVAILABILITY = {"AVAILABLE", "UNAVAILABLE"}
EXECUTION = {
    "READY", "ACTIVE", "INTERRUPTED", "FEED_HOLD", "STOPPED", "OPTIONAL_STOP",
    "PROGRAM_STOPPED", "PROGRAM_COMPLETED", "WAIT", "UNAVAILABLE",
}  # fmt: skip
CONTROLLER_MODE = {
    "AUTOMATIC", "MANUAL", "MANUAL_DATA_INPUT", "SEMI_AUTOMATIC", "EDIT", "UNAVAILABLE",
}  # fmt: skip
CONDITION_LEVELS = {"NORMAL", "WARNING", "FAULT", "UNAVAILABLE"}
TIMESTAMP = re.compile(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d(\.\d{1,6})?Z")


def paho_client() -> Any:
    """A paho client with the callbacks of either paho line: 1.x (which Sparkplug's encoder
    needs, docs/server.md#sparkplug-b) takes no callback version, 2.x wants one."""
    if hasattr(mqtt, "CallbackAPIVersion"):
        return mqtt.Client(mqtt.CallbackAPIVersion.VERSION2)
    return mqtt.Client()


def require_broker(address: tuple[str, int] = BROKER) -> None:
    """Skip (or fail under CI) when no MQTT broker listens at ``address``."""
    try:
        socket.create_connection(address, 1).close()
    except OSError:
        missing_peer(f"MQTT broker (Mosquitto) at {address[0]}:{address[1]}")


def unique_prefix() -> str:
    """A topic prefix no other test run uses."""
    return f"opendnc-test/{uuid.uuid4().hex[:10]}/area"


@dataclass
class Received:
    topic: str
    payload: bytes
    retain: bool

    def json(self) -> Any:
        return json.loads(self.payload)


@dataclass
class Listener:
    """A plain MQTT client (paho) subscribed to ``prefix/#`` that keeps every message."""

    prefix: str
    port: int = BROKER[1]
    username: str | None = None
    password: str | None = None
    messages: list[Received] = field(default_factory=list)

    def __post_init__(self) -> None:
        self._lock = threading.Lock()
        self._subscribed = threading.Event()
        self.client = paho_client()
        if self.username is not None:
            self.client.username_pw_set(self.username, self.password)
        self.client.on_message = self._on_message
        self.client.on_subscribe = lambda *_args: self._subscribed.set()
        self.client.on_connect = lambda client, *_args: client.subscribe(f"{self.prefix}/#", 1)

    def __enter__(self) -> Listener:
        self.client.connect("127.0.0.1", self.port)
        self.client.loop_start()
        wait_for("the MQTT subscription", self._subscribed.is_set, 20)
        return self

    def __exit__(self, *_exc: object) -> None:
        self.client.disconnect()
        self.client.loop_stop()

    def _on_message(self, _client: Any, _userdata: Any, message: Any) -> None:
        with self._lock:
            self.messages.append(Received(message.topic, bytes(message.payload), message.retain))

    def on(self, topic: str) -> list[Received]:
        """Every message on ``topic`` (relative to the prefix) so far."""
        with self._lock:
            return [m for m in self.messages if m.topic == f"{self.prefix}/{topic}"]

    def last(self, topic: str) -> Received | None:
        found = self.on(topic)
        return found[-1] if found else None


def clear_retained(prefix: str, port: int = BROKER[1]) -> int:
    """Delete every retained message under ``prefix`` (an empty retained payload deletes one),
    so the shared broker does not keep what the tests left; how many there were."""
    marker = f"{prefix}/end-of-retained/{uuid.uuid4().hex}"
    with Listener(prefix, port) as listener:
        listener.client.publish(marker, b"x", qos=1)
        # The broker sends the retained messages on subscribing, before the marker.
        wait_for("the marker", lambda: listener.on(marker.removeprefix(prefix + "/")), 20)
        topics = {m.topic for m in listener.messages if m.retain}
        for topic in topics:
            listener.client.publish(topic, b"", qos=1, retain=True).wait_for_publish(10)
    return len(topics)


class ShdrReader:
    """An agent's view of one SHDR adapter, parsing every line strictly.

    Conditions and messages have their own field layouts; every other line is
    ``timestamp|key|value|key|value...``. A line that breaks the rules fails the test.
    """

    CONDITIONS: ClassVar[frozenset[str]] = frozenset({"system"})
    MESSAGES: ClassVar[frozenset[str]] = frozenset({"message", "dprnt"})

    def __init__(self, port: int) -> None:
        self.sock = socket.create_connection(("127.0.0.1", port), 10)
        self.sock.settimeout(0.2)
        self.buffer = b""
        self.values: dict[str, str] = {}
        self.conditions: dict[str, dict[str, str]] = {}  # key -> native code -> level
        self.pongs: list[int] = []
        self.lines: list[str] = []

    def close(self) -> None:
        self.sock.close()

    def send(self, line: str) -> None:
        self.sock.sendall(line.encode("ascii") + b"\n")

    def pump(self) -> None:
        """Read what has arrived and apply it."""
        try:
            chunk = self.sock.recv(65536)
        except TimeoutError:
            return
        if not chunk:
            raise AssertionError("the adapter hung up")
        self.buffer += chunk
        while b"\n" in self.buffer:
            raw, self.buffer = self.buffer.split(b"\n", 1)
            self.apply(raw.decode("utf-8"))

    def apply(self, line: str) -> None:
        assert "\r" not in line, repr(line)
        self.lines.append(line)
        if line.startswith("*"):
            match = re.fullmatch(r"\* PONG (\d+)", line)
            assert match, f"unexpected command line {line!r}"
            self.pongs.append(int(match.group(1)))
            return
        fields = line.split("|")
        assert TIMESTAMP.fullmatch(fields[0]), f"bad timestamp in {line!r}"
        key = fields[1]
        if key in self.CONDITIONS:
            assert len(fields) == 7, f"a condition has 7 fields: {line!r}"
            level, code = fields[2], fields[3]
            assert level in CONDITION_LEVELS, line
            active = self.conditions.setdefault(key, {})
            if level in ("NORMAL", "UNAVAILABLE") and not code:
                active.clear()  # NORMAL without a code clears every active condition
                active[""] = level
            elif level == "NORMAL":
                active.pop(code, None)
            else:
                active.pop("", None)
                active[code] = level
        elif key in self.MESSAGES:
            assert len(fields) == 4, f"a message has 4 fields: {line!r}"
            self.values[key] = fields[3]
        else:
            assert len(fields) % 2 == 1, f"key|value pairs expected: {line!r}"
            for name, value in zip(fields[1::2], fields[2::2], strict=True):
                assert name, line
                assert name not in self.CONDITIONS | self.MESSAGES, line
                assert value != "", f"empty value for {name}: {line!r}"
                self.values[name] = value
        for name, allowed in (
            ("availability", AVAILABILITY),
            ("execution", EXECUTION),
            ("controller_mode", CONTROLLER_MODE),
        ):
            if name in self.values:
                assert self.values[name] in allowed, f"{name}={self.values[name]!r}"

    def until(self, what: str, check: Any, timeout: float = 30) -> Any:
        def step() -> Any:
            self.pump()
            return check()

        return wait_for(what, step, timeout, describe=lambda: self.lines[-20:])


def start_outputs_server(
    tmp_path: Path,
    procs: Procs,
    fleet: Any,
    extra: str,
    *,
    name: str = "dnc-test",
    db: str | None = None,
) -> int:
    """``opendnc serve`` for ``fleet`` with the ``extra`` TOML appended (on the database
    ``db``, SQLite in ``tmp_path`` without it); its HTTP port."""
    from tests.server.harness import serve

    # The configured bind is replaced by a port the system picks (harness.serve says why).
    text = server_config(
        fleet, bind="127.0.0.1:0", poll_interval=0.2, library=tmp_path / "lib", check="warn"
    )
    text = text.replace("[server]\n", f'[server]\nname = "{name}"\n', 1)
    config = tmp_path / "shop.toml"
    config.write_text(text + "\n" + extra)
    url = serve(procs, config, db or f"sqlite:///{tmp_path / 'opendnc.db'}")
    return int(url.rstrip("/").rsplit(":", 1)[1])
