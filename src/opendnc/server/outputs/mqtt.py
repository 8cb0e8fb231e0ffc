"""The MQTT publisher: the machines' state for the rest of the factory (docs/server.md#mqtt).

A subscriber of the event bus like the API's server-sent events. Per machine it keeps a
retained JSON state (``<prefix>/<machine>/status``) and one retained topic per item
(``<prefix>/<machine>/<item>``), both sent only when an item changes (report by exception),
and sends job events and printed lines (``<prefix>/<machine>/jobs`` and ``.../dprnt``, not
retained). The server's health is
``<prefix>/opendnc/<server>/online``: "true" (retained) while connected, "false" as the last
will the broker publishes when the server dies.

The broker never holds anything up: messages wait in a bounded queue that drops its oldest one
when full (``dropped`` counts them), the link is made again with backoff (1 s up to 60 s), and
every (re)connection sends the whole state first, so retained topics are right again at once.
A machine this server lets go (a cluster's lease moved, or the server stops) and, on a clean
stop, every machine still known is published unavailable with the reason, retained.
aiomqtt is imported only when an output runs (here and in :mod:`opendnc.server.outputs.broker`,
the link both outputs share): the server's core runs without it.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import uuid
from collections import deque
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import TYPE_CHECKING, Any

from opendnc.errors import InputError
from opendnc.server.config.shop import MqttConfig
from opendnc.server.core.events import (
    DprntLinePrinted,
    Event,
    EventBus,
    JobEvent,
    LeaseChanged,
    MachineStatusChanged,
)
from opendnc.server.core.state import State
from opendnc.server.outputs.broker import BrokerLink, Will
from opendnc.server.outputs.items import ITEMS, SERVER_STOPPED, ItemTracker, Reading, shdr_time

if TYPE_CHECKING:
    import aiomqtt

    from opendnc.server.core.events import Subscription

__all__ = ["MqttPublisher", "Outgoing", "item_payload", "status_payload"]

log = logging.getLogger(__name__)

STATE_SECONDS = 1.5
"""Of a clean stop's 2 s with the broker (server/outputs/broker.py), what the machines' offline
state may take: the rest is for the health topic's "false"."""

_UNITS = {spec.key: spec.units for spec in ITEMS if spec.units}


@dataclass(frozen=True)
class Outgoing:
    """One message to publish."""

    topic: str
    payload: str
    retain: bool


def item_payload(key: str, reading: Reading) -> dict[str, Any]:
    """An item as MQTT carries it: value, timestamp, quality (and unit where it has one).

    The keys are the same whatever the value, so a consumer reads every item alike; an
    unknown value is ``null`` with quality ``unavailable``.
    """
    value: Any = list(reading.value) if isinstance(reading.value, tuple) else reading.value
    data: dict[str, Any] = {
        "value": value,
        "timestamp": shdr_time(reading.timestamp),
        "quality": "good" if reading.value is not None else "unavailable",
    }
    if key in _UNITS:
        data["unit"] = _UNITS[key]
    return data


def status_payload(
    machine: str, readings: dict[str, Reading], state: State | None = None
) -> dict[str, Any]:
    """A machine's whole state: the classifier's word for it, every item, and when the newest
    of them changed."""
    newest = max(r.timestamp for r in readings.values())
    return {
        "machine": machine,
        "state": (state or State.UNKNOWN).value,
        "timestamp": shdr_time(newest),
        "items": {key: item_payload(key, readings[key]) for key in readings},
    }


def _dumps(data: Any) -> str:
    return json.dumps(data, separators=(",", ":"), ensure_ascii=False)


class MqttPublisher:
    """Publishes the fleet's state to one broker; :meth:`run` until cancelled."""

    def __init__(
        self,
        config: MqttConfig,
        server_name: str,
        machines: list[str],
        bus: EventBus,
        *,
        min_backoff: float = 1.0,
        max_backoff: float = 60.0,
    ) -> None:
        self.config = config
        self.bus = bus
        self.tracker = ItemTracker(machines)
        self.health_topic = f"{config.prefix}/opendnc/{server_name}/online"
        self.identifier = f"opendnc-{server_name}-{uuid.uuid4().hex[:8]}"
        self.link = BrokerLink(
            config, self.identifier, "mqtt", min_backoff=min_backoff, max_backoff=max_backoff
        )
        self.queue: deque[Outgoing] = deque()
        self.dropped = 0  # messages lost to a full queue (broker away or slow)
        self.synced = asyncio.Event()  # set once a connection has sent the whole state
        self._ready = asyncio.Event()
        self._sub: Subscription | None = None

    @property
    def connected(self) -> bool:
        """Whether a session with the broker is up (changes are then queued to be sent)."""
        return self.link.connected

    @connected.setter
    def connected(self, value: bool) -> None:
        self.link.connected = value

    @property
    def connects(self) -> int:
        """How many sessions the broker accepted since the start."""
        return self.link.connects

    def as_json(self) -> dict[str, Any]:
        """The link's state for the API."""
        return {
            "broker": f"{self.config.host}:{self.config.port}",
            "prefix": self.config.prefix,
            "connected": self.connected,
            "connects": self.connects,
            "queued": len(self.queue),
            "dropped": self.dropped,
        }

    def topic(self, machine: str, leaf: str) -> str:
        """``<prefix>/<machine>/<leaf>``."""
        return f"{self.config.prefix}/{machine}/{leaf}"

    # -- from the bus to the queue ---------------------------------------------------------

    def take(self, event: Event) -> None:
        """Turn one bus event into messages (the state is kept even while disconnected)."""
        match event:
            case MachineStatusChanged(served=False):
                pass  # another server of a cluster serves it and publishes it
            case LeaseChanged(machine=machine, held=False):
                # No longer served here (handed over, the server stops, the database lost):
                # the broker must not keep this server's last AVAILABLE for it, so it goes
                # out unavailable with the reason; its next server publishes it from then on.
                reason = event.reason or f"{event.server} no longer serves this machine"
                for changed in self.tracker.stopped(reason, [machine]).values():
                    if changed and self.connected:
                        self._changes(machine, changed)
                self.tracker.forget(machine)
            case MachineStatusChanged(machine=machine):
                first = not self.tracker.known(machine)
                changed = self.tracker.update(event)
                if first and machine in self.tracker.machines:
                    # Known at last: its whole state, once (not UNAVAILABLE at connect and
                    # AVAILABLE a moment later).
                    changed = self.tracker.snapshot(machine)
                if changed and self.connected:
                    # While away, the next connection sends the whole state anyway: queueing
                    # retained changes would only replay older values after it.
                    self._changes(machine, changed)
            case JobEvent(machine=machine) | DprntLinePrinted(machine=machine):
                # Every job event and every printed line is news of its own: not retained,
                # kept in the queue while the broker is away.
                if machine in self.tracker.machines:
                    data = {**event.as_json(), "timestamp": shdr_time(datetime.now(UTC))}
                    leaf = "jobs" if isinstance(event, JobEvent) else "dprnt"
                    self._put(Outgoing(self.topic(machine, leaf), _dumps(data), retain=False))

    def _changes(self, machine: str, changed: dict[str, Reading]) -> None:
        for message in self._machine_messages(machine, changed):
            self._put(message)

    def _machine_messages(self, machine: str, changed: dict[str, Reading]) -> list[Outgoing]:
        out = [self._status_message(machine, self.tracker.snapshot(machine))]
        out += [self._item_message(machine, key, r) for key, r in changed.items()]
        return out

    def _put(self, message: Outgoing) -> None:
        if len(self.queue) >= self.config.queue:
            self.queue.popleft()
            self.dropped += 1
        self.queue.append(message)
        self._ready.set()

    def _whole_state(self) -> list[Outgoing]:
        out = []
        for machine in self.tracker.machines:
            if self.tracker.known(machine):  # the others follow with their first status
                out += self._machine_messages(machine, self.tracker.snapshot(machine))
        return out

    def _stop_messages(self) -> list[Outgoing]:
        """What a clean stop publishes: every known machine unavailable (retained), so the
        broker does not keep saying AVAILABLE for machines nobody watches any more."""
        out = []
        for machine, changed in self.tracker.stopped(SERVER_STOPPED).items():
            out += self._machine_messages(machine, changed)
        return out

    # A machine's state is retained, so a subscriber that comes later reads it at once.

    def _status_message(self, machine: str, readings: dict[str, Reading]) -> Outgoing:
        payload = _dumps(status_payload(machine, readings, self.tracker.state(machine)))
        return Outgoing(self.topic(machine, "status"), payload, retain=True)

    def _item_message(self, machine: str, key: str, reading: Reading) -> Outgoing:
        return Outgoing(self.topic(machine, key), _dumps(item_payload(key, reading)), retain=True)

    # -- from the queue to the broker ------------------------------------------------------

    async def run(self) -> None:
        """Follow the bus and keep a link to the broker, until cancelled."""
        try:
            import aiomqtt  # noqa: F401
        except ImportError:
            raise InputError(
                "[mqtt] needs aiomqtt (the 'server' extra): pip install 'opendnc[server]'"
            ) from None
        with self.bus.subscribe(maxsize=self.config.queue) as sub:
            self._sub = sub
            follow = asyncio.create_task(self._follow(sub), name="mqtt-follow")
            try:
                await self.link.run(
                    self._session, self._will, stopping=self._say_stopped, after=self._session_ended
                )
            finally:
                follow.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await follow

    async def _follow(self, sub: Subscription) -> None:
        while True:
            event = await sub.next()
            if sub.take_overflow():
                log.warning("mqtt: fell behind the event bus; some events were dropped")
            try:
                self.take(event)
            except Exception:  # one odd event must not end the output
                log.exception("mqtt: cannot publish %s event %s", event.kind, event.key)

    def _will(self) -> Will:
        # retained: a subscriber that comes later still reads that the server is gone
        return Will(self.health_topic, "false", qos=1, retain=True)

    def _session_ended(self) -> None:
        self.synced.clear()

    async def _say_stopped(self, client: aiomqtt.Client) -> None:
        # The state that changed before the stop goes out first: the events not followed yet
        # (a cluster's stop lets every machine go just before the outputs stop) and the
        # retained messages still queued; then every machine still known here as stopped,
        # then the health. Job events still queued are left: the state comes first.
        if self._sub is not None:
            for event in self._sub.drain():
                with contextlib.suppress(Exception):
                    self.take(event)
        states = [m for m in self.queue if m.retain] + self._stop_messages()
        self.queue.clear()
        # Each machine's whole status and its availability before the other items (a stable
        # sort: one topic's messages keep their order), so a broker too slow for all of them
        # within the stop has those. One at a time: handing aiomqtt several at once was
        # slower (benchmarks/outputs.py --broker: 200 of 500 machines in 2 s, against 500).
        states.sort(key=lambda m: 0 if m.topic.endswith(("/status", "/availability")) else 1)
        # The clock is read between two messages rather than a timeout cancelling one: the
        # client's wait for an acknowledgement can swallow a cancel (asyncio.wait_for, Python
        # 3.11), and the health must go out whatever the state took.
        loop = asyncio.get_running_loop()
        end = loop.time() + STATE_SECONDS
        for sent, message in enumerate(states):
            if loop.time() >= end:
                log.warning("mqtt: the broker took %.1f s for %d of the stop's %d messages",
                            STATE_SECONDS, sent, len(states))  # fmt: skip
                break
            await client.publish(message.topic, message.payload, qos=1, retain=True)
        await client.publish(self.health_topic, "false", qos=1, retain=True)

    async def _session(self, client: aiomqtt.Client) -> None:
        # The whole state supersedes every retained change still queued; job events stay.
        jobs = [m for m in self.queue if not m.retain]
        self.queue.clear()
        self.queue.extend(jobs)
        if self.dropped:
            log.warning("mqtt: %d messages were dropped while the broker was away", self.dropped)
        await client.publish(self.health_topic, "true", qos=1, retain=True)
        for message in self._whole_state():
            await client.publish(message.topic, message.payload, qos=1, retain=True)
        self.synced.set()
        while True:
            if not self.queue:
                self._ready.clear()
                await self._ready.wait()
                continue
            message = self.queue[0]
            await client.publish(message.topic, message.payload, qos=1, retain=message.retain)
            # Taken off only once the broker has it: a message lost with the link goes again.
            if self.queue and self.queue[0] is message:
                self.queue.popleft()
