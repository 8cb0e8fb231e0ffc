"""The MTConnect SHDR adapter: each machine is one MTConnect device on its own TCP port
(docs/server.md#mtconnect).

An MTConnect agent connects to an adapter and reads lines ``timestamp|key|value|key|value``;
it sends ``* PING`` and expects ``* PONG <ms>``, the time within which it may count on the
next answer. On every connection the adapter sends its whole state first: an agent marks all
of a device's items UNAVAILABLE when its adapter goes away. Afterwards only changes follow.

The line format is built by pure functions (:func:`event_line`, :func:`message_line`,
:func:`condition_lines`), the sockets by :class:`ShdrAdapter`; :class:`MtconnectOutput` follows
the event bus and feeds one adapter per machine.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import logging
from collections.abc import Iterable
from datetime import UTC, datetime
from typing import Any
from xml.etree import ElementTree as ET

from opendnc.server.config.shop import ConfigError, MtconnectConfig
from opendnc.server.core.events import DprntLinePrinted, EventBus, MachineStatusChanged
from opendnc.server.outputs.items import (
    ITEMS,
    SERVER_STOPPED,
    ItemSpec,
    ItemTracker,
    Reading,
    Value,
    shdr_time,
)

__all__ = [
    "DPRNT",
    "HEARTBEAT_MS",
    "MTCONNECT_VERSION",
    "MtconnectOutput",
    "ShdrAdapter",
    "condition_lines",
    "devices_xml",
    "event_line",
    "message_line",
    "shdr_state",
]

log = logging.getLogger(__name__)

HEARTBEAT_MS = 10000
"""What ``* PONG`` announces: the agent may drop the link after this long without an answer."""

WRITE_LIMIT = 1 << 20
"""Bytes an agent may leave unread before the adapter drops it (it reconnects and gets the whole
state again): a stalled agent must not make the server hoard memory."""

UNAVAILABLE = "UNAVAILABLE"
DPRNT = ItemSpec("dprnt", "MESSAGE", component="controller")
"""The lines a Haas prints (DPRNT), one MESSAGE observation each; not part of the status."""

_CONDITION = {spec.key for spec in ITEMS if spec.category == "CONDITION"}
_MESSAGE = {spec.key for spec in (*ITEMS, DPRNT) if spec.type == "MESSAGE"}


def _text(value: str) -> str:
    # SHDR has no escape: a '|' would start a new field and a line break a new line.
    return " ".join(value.replace("|", "/").split())


def render(value: Value) -> str:
    """A value as it goes on the wire; None is UNAVAILABLE."""
    if value is None:
        return UNAVAILABLE
    if isinstance(value, bool):  # not a value an item has, but never "True"
        return str(value).upper()
    if isinstance(value, float):
        return f"{value:g}"
    text = _text(", ".join(value) if isinstance(value, tuple) else str(value))
    # An empty field would read as a missing one: a blank text is no value.
    return text or UNAVAILABLE


def event_line(timestamp: str, values: Iterable[tuple[str, Value]]) -> str:
    """``timestamp|key|value|key|value...`` for events and samples."""
    fields = [timestamp]
    for key, value in values:
        fields += [key, render(value)]
    return "|".join(fields)


def message_line(timestamp: str, key: str, value: Value, native_code: str = "") -> str:
    """A MESSAGE has a native code before its text: ``timestamp|key|code|text``."""
    return f"{timestamp}|{key}|{_text(native_code)}|{render(value)}"


def fault_code(text: str) -> str:
    """A native code for a fault the control names only by its text (stable across polls)."""
    return "E" + hashlib.sha1(text.encode("utf-8")).hexdigest()[:8].upper()


def condition_lines(
    timestamp: str, key: str, faults: Value, before: tuple[str, ...] | None = None
) -> list[str]:
    """Condition lines ``timestamp|key|level|native_code|native_severity|qualifier|text``.

    ``faults`` None is UNAVAILABLE, an empty tuple NORMAL; each fault is active under its own
    native code. ``before`` (what the agent was told last) lets a change clear only the faults
    that went away, instead of flapping every active one through NORMAL.
    """
    if faults is None:
        return [f"{timestamp}|{key}|{UNAVAILABLE}||||"]
    if not isinstance(faults, tuple) or not faults:
        return [f"{timestamp}|{key}|NORMAL||||"]
    lines = [
        f"{timestamp}|{key}|NORMAL|{fault_code(gone)}|||"
        for gone in before or ()
        if gone not in faults
    ]
    lines += [
        f"{timestamp}|{key}|FAULT|{fault_code(text)}|||{_text(text)}"
        for text in faults
        if not before or text not in before
    ]
    return lines


def shdr_state(readings: dict[str, Reading], before: dict[str, Value] | None = None) -> list[str]:
    """The lines for ``readings`` (all of a machine's items, or the ones that changed).

    Events that changed at the same time share a line; messages and conditions have lines of
    their own, as their fields differ. ``before`` holds the conditions' previous values.
    """
    lines: list[str] = []
    events: dict[str, list[tuple[str, Value]]] = {}
    for key, reading in readings.items():
        timestamp = shdr_time(reading.timestamp)
        if key in _CONDITION:
            previous = (before or {}).get(key)
            lines += condition_lines(
                timestamp, key, reading.value, previous if isinstance(previous, tuple) else None
            )
        elif key in _MESSAGE:
            lines.append(message_line(timestamp, key, reading.value))
        else:
            events.setdefault(timestamp, []).append((key, reading.value))
    return [event_line(ts, values) for ts, values in events.items()] + lines


class ShdrAdapter:
    """One machine's SHDR port: any number of agents, each sent the whole state on connect."""

    def __init__(self, machine: str, host: str, port: int, tracker: ItemTracker) -> None:
        self.machine = machine
        self.host = host
        self.port = port
        self.tracker = tracker
        self.dprnt = Reading(None, datetime.now(UTC))  # the last printed line
        self._server: asyncio.Server | None = None
        self._clients: set[asyncio.StreamWriter] = set()
        self._handlers: set[asyncio.Task[None]] = set()

    async def start(self) -> None:
        """Listen (port 0 takes a free port; :attr:`port` then tells which)."""
        self._server = await asyncio.start_server(self._serve, self.host, self.port)
        self.port = self._server.sockets[0].getsockname()[1]

    @property
    def agents(self) -> int:
        """How many agents are connected."""
        return len(self._clients)

    @property
    def listening(self) -> bool:
        """Whether the port is open."""
        return self._server is not None

    async def close(self) -> None:
        """Stop listening and hang up on every agent."""
        if self._server is not None:
            self._server.close()
        for writer in list(self._clients):
            writer.close()
        for task in list(self._handlers):
            task.cancel()
        await asyncio.gather(*self._handlers, return_exceptions=True)
        if self._server is not None:
            await self._server.wait_closed()
            self._server = None

    def send(self, lines: list[str]) -> None:
        """Write ``lines`` to every agent; one that does not read them is dropped."""
        if not lines:
            return
        data = "".join(line + "\n" for line in lines).encode("utf-8")
        for writer in list(self._clients):
            if writer.transport.get_write_buffer_size() > WRITE_LIMIT:
                log.warning("mtconnect %s: an agent stopped reading; dropped", self.machine)
                self._clients.discard(writer)
                writer.close()
                continue
            writer.write(data)

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        if task is not None:
            self._handlers.add(task)
        try:
            snapshot = {**self.tracker.snapshot(self.machine), DPRNT.key: self.dprnt}
            writer.write("".join(f"{line}\n" for line in shdr_state(snapshot)).encode("utf-8"))
            self._clients.add(writer)
            while True:
                raw = await reader.readline()
                if not raw:
                    break
                if raw.strip() == b"* PING":
                    writer.write(f"* PONG {HEARTBEAT_MS}\n".encode("ascii"))
        except (ConnectionError, asyncio.LimitOverrunError, ValueError):
            pass  # an agent that hangs up or sends garbage is simply gone
        finally:
            self._clients.discard(writer)
            writer.close()
            with contextlib.suppress(Exception):
                await writer.wait_closed()
            if task is not None:
                self._handlers.discard(task)


class MtconnectOutput:
    """Follows the event bus and keeps one :class:`ShdrAdapter` per machine up to date."""

    def __init__(self, config: MtconnectConfig, machines: list[str], bus: EventBus) -> None:
        self.bus = bus
        self.tracker = ItemTracker(machines)
        self.adapters = {
            name: ShdrAdapter(name, config.host, config.ports[name], self.tracker)
            for name in machines
        }
        self._conditions: dict[str, dict[str, Value]] = {name: {} for name in machines}

    async def start(self) -> None:
        """Open every machine's port (again: nothing); a port that is taken is a
        :class:`ConfigError` naming the machine."""
        for adapter in self.adapters.values():
            if adapter.listening:
                continue
            try:
                await adapter.start()
            except OSError as exc:
                await self.close()
                where = f"{adapter.host}:{adapter.port}"
                raise ConfigError(
                    "mtconnect", f"{adapter.machine}: cannot listen on {where}: {exc.strerror}"
                ) from exc
            log.info("mtconnect: %s on %s:%d", adapter.machine, adapter.host, adapter.port)

    def as_json(self) -> dict[str, Any]:
        """Each machine's port and how many agents read it, for the API."""
        return {
            name: {"port": a.port, "listening": a.listening, "agents": a.agents}
            for name, a in self.adapters.items()
        }

    async def close(self) -> None:
        """Tell every agent its machine is unavailable now, then close every port."""
        for machine, changed in self.tracker.stopped(SERVER_STOPPED).items():
            self._send_changes(machine, changed)
        for adapter in self.adapters.values():
            await adapter.close()

    async def run(self) -> None:
        """Send every change, until cancelled."""
        with self.bus.subscribe() as sub:
            while True:
                event = await sub.next()
                try:
                    match event:
                        case MachineStatusChanged():
                            self.take(event)
                        case DprntLinePrinted():
                            self.printed(event)
                except Exception:  # one odd event must not end the output
                    log.exception("mtconnect: cannot send %s event %s", event.kind, event.key)

    def take(self, event: MachineStatusChanged) -> None:
        """Report the items of a machine's status event that changed."""
        self._send_changes(event.machine, self.tracker.update(event))

    def _send_changes(self, machine: str, changed: dict[str, Reading]) -> None:
        adapter = self.adapters.get(machine)
        if not changed or adapter is None:
            return
        before = self._conditions[machine]
        lines = shdr_state(changed, before)
        for key in _CONDITION & changed.keys():
            before[key] = changed[key].value
        adapter.send(lines)

    def printed(self, event: DprntLinePrinted) -> None:
        """Send a DPRNT line (every one: two equal measurements are two observations)."""
        adapter = self.adapters.get(event.machine)
        if adapter is None:
            return
        at = datetime.now(UTC)
        with contextlib.suppress(ValueError):
            at = datetime.fromisoformat(event.at)
        adapter.dprnt = Reading(event.line or None, at)
        adapter.send([message_line(shdr_time(at), DPRNT.key, adapter.dprnt.value)])


MTCONNECT_VERSION = "1.4"
"""The MTConnect version the Devices file declares: the first whose schema has every data item
the adapter sends (LINE_NUMBER with subType ABSOLUTE came with 1.4)."""


def devices_xml(machines: list[str], server_name: str) -> str:
    """An MTConnect Devices document for an agent: one device per machine, its data items
    named by the SHDR keys (ids are made unique across the document). It validates against
    the MTConnectDevices schema of :data:`MTCONNECT_VERSION`."""
    ns = f"urn:mtconnect.org:MTConnectDevices:{MTCONNECT_VERSION}"
    root = ET.Element("MTConnectDevices", xmlns=ns)
    ET.SubElement(
        root,
        "Header",
        creationTime=datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
        sender=server_name,
        instanceId="1",
        version=MTCONNECT_VERSION,
        bufferSize="131072",
        # The server keeps no assets, but the schema's least buffer is one asset.
        assetBufferSize="1",
        assetCount="0",
    )
    devices = ET.SubElement(root, "Devices")
    taken: set[str] = set()
    for name in machines:
        # XML ids: a letter first, no '-' or '.'; "mill-1" and "mill_1" must still differ.
        base = "".join(c if c.isalnum() else "_" for c in name)
        base = base if base[0].isalpha() else f"m{base}"
        ident, n = base, 1
        while ident.lower() in taken:
            n += 1
            ident = f"{base}_{n}"
        taken.add(ident.lower())
        device = ET.SubElement(
            devices, "Device", id=ident, name=name, uuid=f"opendnc-{server_name}-{name}"
        )
        ET.SubElement(device, "Description").text = f"{name} through opendnc {server_name}"
        parents = {"device": ET.SubElement(device, "DataItems")}
        components = ET.SubElement(device, "Components")
        controller = ET.SubElement(components, "Controller", id=f"{ident}_cont", name="controller")
        parents["controller"] = ET.SubElement(controller, "DataItems")
        path = ET.SubElement(
            ET.SubElement(controller, "Components"), "Path", id=f"{ident}_path", name="path"
        )
        parents["path"] = ET.SubElement(path, "DataItems")
        for spec in (*ITEMS, DPRNT):
            attrs = {
                "category": spec.category,
                "id": f"{ident}_{spec.key}",
                "name": spec.key,
                "type": spec.type,
            }
            if spec.sub_type:
                attrs["subType"] = spec.sub_type
            if spec.units:
                attrs["units"] = spec.units
            ET.SubElement(parents[spec.component], "DataItem", attrs)
    ET.indent(root)
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode")
