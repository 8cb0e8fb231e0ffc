"""The Sparkplug B edge node: the machines' state for a SCADA host (docs/server.md#sparkplug-b).

The server is one edge node (``spBv1.0/<group>/.../<node>``) and each machine it serves is a
device of it. A subscriber of the event bus like the plain MQTT output, beside it:

* each MQTT session takes the next ``bdSeq`` (kept in the database), registers an NDEATH
  carrying it as the MQTT will, and starts with NBIRTH (``seq`` 0, the bdSeq, the
  ``Node Control/Rebirth`` metric) and a DBIRTH for every machine served and read;
* a machine this server starts serving (:class:`~opendnc.server.core.events.LeaseChanged`: a
  single server holds every machine from its start, a cluster's server the ones whose lease
  it holds) is born (DBIRTH) at its first status that the control answered; one it stops
  serving, or whose control stops answering, dies (DDEATH), and the latter is born again
  when the control answers;
* a clean stop sends a DDEATH for every device born, then the node's NDEATH;
* a status that changes metrics sends DDATA with only those metrics, by alias;
* every message after NBIRTH takes the next ``seq`` (0..255, then 0 again);
* an NCMD with ``Node Control/Rebirth`` true births the node and its devices again;
* with a primary host configured, nothing is born until the host's STATE
  (``spBv1.0/STATE/<host>``) says online, and a STATE offline ends the session (NDEATH, a new
  connection, waiting again).

Nothing is queued while the broker is away: Sparkplug's births carry the whole state, and
every session starts with them. pysparkplug encodes the payloads; aiomqtt carries them (the
same client as the JSON output), and both are imported only when ``[sparkplug]`` is there.
"""

from __future__ import annotations

import asyncio
import contextlib
import importlib
import json
import logging
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from datetime import datetime
from enum import Enum
from typing import TYPE_CHECKING, Any

from opendnc.errors import InputError
from opendnc.server.config.shop import SparkplugConfig
from opendnc.server.core.components import cancel_and_wait
from opendnc.server.core.events import EventBus, LeaseChanged, MachineStatusChanged
from opendnc.server.core.state import State
from opendnc.server.outputs.broker import BrokerLink, ReconnectNow, Will
from opendnc.server.outputs.items import items_of
from opendnc.server.outputs.sparkplug_store import BD_SEQ_MODULO

if TYPE_CHECKING:
    import aiomqtt

    from opendnc.server.core.events import Subscription

__all__ = [
    "BD_SEQ",
    "DEVICE_METRICS",
    "REBIRTH",
    "Kind",
    "Outgoing",
    "SparkplugNode",
    "host_state",
]

log = logging.getLogger(__name__)

BD_SEQ = "bdSeq"
REBIRTH = "Node Control/Rebirth"
SOFTWARE = "Node Info/Software"


class Kind(Enum):
    """A metric's Sparkplug datatype, by name (mapped to pysparkplug's at encoding)."""

    STRING = "STRING"
    INT64 = "INT64"
    DOUBLE = "DOUBLE"
    BOOLEAN = "BOOLEAN"


Value = str | int | float | bool | None

DEVICE_METRICS: tuple[tuple[str, Kind], ...] = (
    ("state", Kind.STRING),  # the classifier's word (server/core/state.py)
    ("availability", Kind.STRING),  # the items' (server/outputs/items.py), by MTConnect's words
    ("execution", Kind.STRING),
    ("controller_mode", Kind.STRING),
    ("program", Kind.STRING),
    ("line_number", Kind.INT64),
    ("part_count", Kind.INT64),
    ("tool_number", Kind.INT64),
    ("feed_override", Kind.DOUBLE),
    ("rapid_override", Kind.DOUBLE),
    ("spindle_override", Kind.DOUBLE),
    ("message", Kind.STRING),
    ("alarm", Kind.BOOLEAN),  # the control reports errors
    ("alarms", Kind.STRING),  # those errors, one a line
)
"""Each device's metrics, in the order of their aliases."""

_KINDS = dict(DEVICE_METRICS)
# Aliases are unique across the node's metrics and all its devices' (Sparkplug B 3.0): the
# node's are small, device number i (configuration order) has i * _ALIAS_BLOCK + 1 and up.
_NODE_ALIASES = {REBIRTH: 1, SOFTWARE: 2}
_ALIAS_BLOCK = 1000


def device_values(event: MachineStatusChanged) -> dict[str, Value]:
    """A device's metric values from a machine's status event (None: unknown, sent as null)."""
    items = items_of(event)
    values: dict[str, Value] = {"state": event.state.value}
    for name, kind in DEVICE_METRICS:
        if name in items and name != "system":
            value = items[name]
            if value is None or isinstance(value, tuple):
                values[name] = None
            elif kind is Kind.INT64:
                values[name] = int(value)
            elif kind is Kind.DOUBLE:
                values[name] = float(value)
            else:
                values[name] = str(value)
    errors = items["system"]
    values["alarm"] = bool(errors) if isinstance(errors, tuple) else None
    values["alarms"] = "\n".join(errors) if isinstance(errors, tuple) else None
    return values


def host_state(payload: bytes) -> tuple[bool, int] | None:
    """A primary host's STATE: (online, timestamp in ms), or None if it is not one.

    Sparkplug B 3.0 sends JSON ``{"online": true, "timestamp": 1700000000000}``; the older
    2.2 hosts send the word ``ONLINE`` or ``OFFLINE`` (no timestamp: 0).
    """
    text = payload.decode("utf-8", "replace").strip()
    if text in ("ONLINE", "OFFLINE"):
        return text == "ONLINE", 0
    try:
        data = json.loads(text)
    except ValueError:
        return None
    if not isinstance(data, dict):
        return None
    online, stamp = data.get("online"), data.get("timestamp", 0)
    if not isinstance(online, bool) or isinstance(stamp, bool) or not isinstance(stamp, int):
        return None
    return online, stamp


def _ms(at: datetime | None = None) -> int:
    return int((at.timestamp() if at is not None else time.time()) * 1000)


@dataclass(frozen=True)
class Outgoing:
    """One Sparkplug message: topic, encoded payload, QoS."""

    topic: str
    payload: bytes
    qos: int = 0


class SparkplugNode:
    """The edge node; a component (started by the outputs, before the machines' tasks)."""

    name = "sparkplug"
    needs: tuple[str, ...] = ("machines",)

    def __init__(
        self,
        config: SparkplugConfig,
        machines: list[str],
        bus: EventBus,
        next_bd_seq: Callable[[], int],
        *,
        min_backoff: float = 1.0,
        max_backoff: float = 60.0,
    ) -> None:
        self.config = config
        self.machines = list(machines)
        self._names = frozenset(machines)
        self.bus = bus
        self.next_bd_seq = next_bd_seq  # blocking (the database): run in a thread
        self.link = BrokerLink(
            config.broker,
            f"opendnc-spb-{config.node}-{uuid.uuid4().hex[:8]}",
            "sparkplug",
            clean_session=True,
            min_backoff=min_backoff,
            max_backoff=max_backoff,
        )
        self.identifier = self.link.identifier
        self._aliases = {
            (machine, name): (index + 1) * _ALIAS_BLOCK + offset
            for index, machine in enumerate(self.machines)
            for offset, (name, _kind) in enumerate(DEVICE_METRICS, start=1)
        }
        # What the node knows (kept while the broker is away) ...
        self.served: set[str] = set()
        self.values: dict[str, dict[str, Value]] = {}  # machine -> metric -> value
        self.stamps: dict[str, int] = {}  # machine -> its last status's time (ms)
        self._dirty: set[str] = set()
        # ... and what this session told the broker.
        self.bd_seq: int | None = None
        self.seq = 0
        self.node_born = False
        self.born: dict[str, dict[str, Value]] = {}  # machine -> values the host has
        self.host_online = not config.primary_host
        self._host_stamp = -1
        self._rebirth = False
        self._host_left = False
        self.nbirths = 0  # NBIRTHs sent (a rebirth counts)
        self._wake = asyncio.Event()
        self._sub_cm: contextlib.AbstractContextManager[Subscription] | None = None
        self._sub: Subscription | None = None
        self._task: asyncio.Task[None] | None = None
        self._spb: Any = None

    # -- the component ----------------------------------------------------------------------

    async def start(self) -> None:
        """Subscribe to the bus at once (the machines' tasks start after this), then run."""
        self._spb = _import()
        self._sub_cm = self.bus.subscribe(maxsize=10_000)
        self._sub = self._sub_cm.__enter__()
        self._task = asyncio.create_task(self.run(), name="sparkplug")

    async def stop(self) -> None:
        """Send the node's death (bounded), disconnect, unsubscribe."""
        task, self._task = self._task, None
        if task is not None:
            await cancel_and_wait(task)
        cm, self._sub_cm, self._sub = self._sub_cm, None, None
        if cm is not None:
            cm.__exit__(None, None, None)

    @property
    def connected(self) -> bool:
        """Whether a session with the broker is up."""
        return self.link.connected

    @property
    def connects(self) -> int:
        """How many sessions the broker accepted since the start."""
        return self.link.connects

    def as_json(self) -> dict[str, Any]:
        """The node's state for the API."""
        return {
            "broker": f"{self.config.broker.host}:{self.config.broker.port}",
            "group": self.config.group,
            "node": self.config.node,
            "primary_host": self.config.primary_host or None,
            "host_online": self.host_online,
            "connected": self.connected,
            "connects": self.connects,
            "bd_seq": self.bd_seq,
            "born": self.node_born,
            "devices": sorted(self.born),
        }

    # -- topics -----------------------------------------------------------------------------

    def topic(self, kind: str, device: str | None = None) -> str:
        """``spBv1.0/<group>/<kind>/<node>[/<device>]``."""
        base = f"spBv1.0/{self.config.group}/{kind}/{self.config.node}"
        return f"{base}/{device}" if device is not None else base

    @property
    def state_topic(self) -> str:
        """The primary host's STATE topic (Sparkplug B 3.0)."""
        return f"spBv1.0/STATE/{self.config.primary_host}"

    # -- from the bus to what the node knows -------------------------------------------------

    def take(self, event: object) -> None:
        """Fold one bus event into what the node knows; the session sends what changed."""
        match event:
            case LeaseChanged(machine=machine, held=held) if machine in self._names:
                if held:
                    self.served.add(machine)
                else:
                    self.served.discard(machine)
                # A machine gained again is born with a status read after it was gained.
                self.values.pop(machine, None)
            case MachineStatusChanged(machine=machine) if machine in self.served:
                self.values[machine] = device_values(event)
                at = event.status.at if event.status is not None else None
                self.stamps[machine] = _ms(at)
            case _:
                return
        self._dirty.add(machine)
        self._wake.set()

    # -- what to send ------------------------------------------------------------------------

    def _next_seq(self) -> int:
        self.seq = (self.seq + 1) % 256
        return self.seq

    def _metric(self, name: str, kind: Kind, value: Value, *, alias: int | None, at: int) -> Any:
        p = self._spb
        return p.Metric(
            timestamp=at,
            name=name,
            datatype=getattr(p.DataType, kind.value),
            value=value,
            alias=alias,
        )

    def death(self) -> Outgoing:
        """The NDEATH of this session (the MQTT will, and a clean stop's last word)."""
        p = self._spb
        metric = self._metric(BD_SEQ, Kind.INT64, self.bd_seq, alias=None, at=_ms())
        payload = p.NDeath(timestamp=_ms(), bd_seq_metric=metric).encode()
        return Outgoing(self.topic("NDEATH"), payload, qos=1)

    def births(self) -> list[Outgoing]:
        """NBIRTH (``seq`` 0) and a DBIRTH for every served machine already read."""
        p = self._spb
        now = _ms()
        from opendnc import __version__

        self.seq = 0
        metrics = (
            self._metric(BD_SEQ, Kind.INT64, self.bd_seq, alias=None, at=now),
            self._metric(REBIRTH, Kind.BOOLEAN, False, alias=_NODE_ALIASES[REBIRTH], at=now),
            self._metric(
                SOFTWARE, Kind.STRING, f"opendnc {__version__}", alias=_NODE_ALIASES[SOFTWARE],
                at=now,
            ),
        )  # fmt: skip
        out = [
            Outgoing(self.topic("NBIRTH"), p.NBirth(timestamp=now, seq=0, metrics=metrics).encode())
        ]
        self.node_born = True
        self.nbirths += 1
        self.born = {}
        self._dirty = set(self.served) | set(self.values)
        out += self.changes()
        return out

    def changes(self) -> list[Outgoing]:
        """DBIRTH, DDATA or DDEATH for each machine whose state changed since the last call."""
        out: list[Outgoing] = []
        dirty, self._dirty = self._dirty, set()
        for machine in [m for m in self.machines if m in dirty]:  # configuration order
            message = self._device_change(machine)
            if message is not None:
                out.append(message)
        return out

    def _ddeath(self, machine: str) -> Outgoing | None:
        """The device's DDEATH if the host has it as born (and it is no longer)."""
        if self.born.pop(machine, None) is None:
            return None
        payload = self._spb.DDeath(timestamp=_ms(), seq=self._next_seq()).encode()
        return Outgoing(self.topic("DDEATH", machine), payload)

    def deaths(self) -> list[Outgoing]:
        """A DDEATH for every device born in this session (a clean stop, before NDEATH)."""
        out = [self._ddeath(machine) for machine in self.machines]
        return [message for message in out if message is not None]

    def _device_change(self, machine: str) -> Outgoing | None:
        p = self._spb
        now = _ms()
        if machine not in self.served:
            return self._ddeath(machine)
        values = self.values.get(machine)
        if values is None:
            return None  # gained, not read yet: born with its first status
        if values["state"] == State.OFFLINE.value:
            # The link to the control is lost: Sparkplug 3.0 (section 5.7) has the edge node
            # publish the device's DDEATH; it is born again once the control answers.
            return self._ddeath(machine)
        at = self.stamps.get(machine, now)
        sent = self.born.get(machine)
        if sent is None:
            metrics = tuple(
                self._metric(name, kind, values[name], alias=self._aliases[machine, name], at=at)
                for name, kind in DEVICE_METRICS
            )
            self.born[machine] = dict(values)
            payload = p.DBirth(timestamp=now, seq=self._next_seq(), metrics=metrics).encode()
            return Outgoing(self.topic("DBIRTH", machine), payload)
        changed = [name for name, _kind in DEVICE_METRICS if sent[name] != values[name]]
        if not changed:
            return None
        # By alias alone: the host has the names from the DBIRTH.
        metrics = tuple(
            p.Metric(
                timestamp=at,
                name=None,
                datatype=getattr(p.DataType, _KINDS[name].value),
                value=values[name],
                alias=self._aliases[machine, name],
            )
            for name in changed
        )
        self.born[machine] = dict(values)
        payload = p.DData(timestamp=now, seq=self._next_seq(), metrics=metrics).encode()
        return Outgoing(self.topic("DDATA", machine), payload)

    # -- from the broker ---------------------------------------------------------------------

    def received(self, topic: str, payload: bytes) -> None:
        """An NCMD or the primary host's STATE."""
        if topic == self.topic("NCMD"):
            try:
                command = self._spb.NCmd.decode(payload)
            except Exception as exc:  # a broken command must not end the session
                log.warning("sparkplug: NCMD not understood: %s", exc)
                return
            for metric in command.metrics:
                if metric.name == REBIRTH and metric.value is True:
                    log.info("sparkplug: rebirth asked for")
                    self._rebirth = True
        elif self.config.primary_host and topic == self.state_topic:
            state = host_state(payload)
            if state is None:
                log.warning("sparkplug: %s: not a STATE payload", topic)
                return
            online, stamp = state
            if stamp and stamp < self._host_stamp:
                return  # an older STATE than the one already seen (Sparkplug B 3.0)
            self._host_stamp = max(self._host_stamp, stamp)
            if online != self.host_online:
                log.info("sparkplug: primary host %s %s", self.config.primary_host,
                         "online" if online else "offline")  # fmt: skip
            if not online and self.node_born:
                self._host_left = True
            self.host_online = online
        else:
            return
        self._wake.set()

    # -- the link ----------------------------------------------------------------------------

    async def run(self) -> None:
        """Follow the bus and keep a session with the broker, until cancelled."""
        follow = asyncio.create_task(self._follow(), name="sparkplug-follow")
        try:
            await self.link.run(
                self._session,
                self._will,
                stopping=self._say_stopped,
                before=self._take_bd_seq,
                after=self._session_ended,
            )
        finally:
            await cancel_and_wait(follow)

    async def _follow(self) -> None:
        sub = self._sub
        assert sub is not None, "start() subscribes"
        while True:
            event = await sub.next()
            if sub.take_overflow():
                log.warning("sparkplug: fell behind the event bus; births follow")
                self._rebirth = True
            try:
                self.take(event)
            except Exception:  # one odd event must not end the output
                log.exception("sparkplug: cannot take %s event %s", event.kind, event.key)

    def _will(self) -> Will:
        # the session's NDEATH, with the bdSeq taken for it just before (Sparkplug 3.0)
        death = self.death()
        return Will(death.topic, death.payload, qos=death.qos, retain=False)

    async def _say_stopped(self, client: aiomqtt.Client) -> None:
        # A clean stop sends the deaths itself (the broker sends the will only when the link
        # dies): each device's, then the node's.
        if self.node_born:
            for message in [*self.deaths(), self.death()]:
                await self._send(client, message)

    def _session_ended(self) -> None:
        self.node_born = False
        self.born = {}
        self._host_left = False
        self.host_online = not self.config.primary_host
        self._host_stamp = -1

    async def _take_bd_seq(self) -> None:
        """A new session, a new bdSeq, stored before connecting (sparkplug_store). With the
        database away the count goes on in memory: the output must not stop for it."""
        try:
            self.bd_seq = await asyncio.to_thread(self.next_bd_seq) % BD_SEQ_MODULO
        except Exception as exc:
            last = self.bd_seq if self.bd_seq is not None else -1
            self.bd_seq = (last + 1) % BD_SEQ_MODULO
            log.warning("sparkplug: bdSeq not stored (%s); using %d", exc, self.bd_seq)

    async def _send(self, client: aiomqtt.Client, message: Outgoing) -> None:
        await client.publish(message.topic, message.payload, qos=message.qos, retain=False)

    async def _session(self, client: aiomqtt.Client) -> None:
        log.info("sparkplug: session with bdSeq %s", self.bd_seq)
        await client.subscribe(self.topic("NCMD"), qos=1)
        if self.config.primary_host:
            await client.subscribe(self.state_topic, qos=1)
        inbound = asyncio.create_task(self._inbound(client), name="sparkplug-inbound")
        try:
            while True:
                if self._host_left:
                    # the host went offline: this session ends with its death, and the next
                    # one (a new bdSeq) waits for the host again
                    await self._send(client, self.death())
                    raise ReconnectNow
                if self.host_online:
                    if not self.node_born or self._rebirth:
                        self._rebirth = False
                        messages = self.births()
                    else:
                        messages = self.changes()
                    for message in messages:
                        await self._send(client, message)
                await self._until_woken(inbound)
        finally:
            await cancel_and_wait(inbound)

    async def _inbound(self, client: aiomqtt.Client) -> None:
        async for message in client.messages:
            payload = message.payload
            data = payload if isinstance(payload, bytes) else str(payload).encode()
            self.received(str(message.topic), data)

    async def _until_woken(self, inbound: asyncio.Task[None]) -> None:
        import aiomqtt

        if self._wake.is_set():
            self._wake.clear()
            return
        waiter = asyncio.create_task(self._wake.wait())
        try:
            await asyncio.wait({waiter, inbound}, return_when=asyncio.FIRST_COMPLETED)
        finally:
            waiter.cancel()
        self._wake.clear()
        if inbound.done():
            inbound.result()  # the link's error ends the session
            raise aiomqtt.MqttError("the broker ended the subscription")


def _import() -> Any:
    try:
        # By name: the types stay Any here, so a checker without the package still passes.
        return importlib.import_module("pysparkplug")
    except ImportError:
        raise InputError(
            "[sparkplug] needs pysparkplug (the 'server' extra): pip install 'opendnc[server]'"
        ) from None
