"""Machines read through an OPC UA server with the umati machine-tool model (OPC 40501-1).

The connector opens a session (security and user as configured), finds the machine object by
its browse names, and *subscribes*: one subscription with a monitored item per value it maps
(channel state and mode, operation mode, feed override, the active program's name, number and
state, the part count, the stacklight's elements) and an event monitored item on
``Notification/Messages`` for alerts. The server sends what changed; a status poll takes the
latest values held here, so a poll costs no request. What the model says is put into our words
here (:func:`machine_status`) and the one classifier (:func:`opendnc.server.core.state.classify`)
files the machine; the mapping is ours, not the specification's (docs/opcua-input.md#mapping).

A lost session (the server restarted, the network went) makes :meth:`OpcuaConnector.status`
raise: the machine's supervisor closes the link and connects again, which browses and
subscribes anew (a restarted server may have given its nodes other ids).
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from asyncua import ua
from asyncua.client.client import Client
from asyncua.common.node import Node
from asyncua.common.subscription import Subscription
from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256
from asyncua.ua.attribute_ids import AttributeIds
from asyncua.ua.object_ids import ObjectIds
from asyncua.ua.uaerrors import UaError

from opendnc.errors import InputError, TransportError
from opendnc.opcua.model import ChannelMode, ChannelState, MachineOperationMode, Paths, ProgramState
from opendnc.server.core.status import MachineStatus
from opendnc.server.kinds.connector import StatusOnly
from opendnc.server.kinds.opcua.schema import OpcuaMachine
from opendnc.server.store.models import utcnow

__all__ = ["Light", "OpcuaConnector", "Readings", "machine_status"]

log = logging.getLogger(__name__)
# asyncua logs a lost server's every failed publish with a traceback, once a second; the loss
# is logged here once, with the reason, and the supervisor logs the reconnect
logging.getLogger("asyncua.client.ua_session").setLevel(logging.CRITICAL)


@dataclass
class Light:
    """One element of the stacklight as last reported."""

    on: bool | None = None
    color: int | None = None


@dataclass
class Readings:
    """The latest value of every subscribed item (None: not reported, or no such node)."""

    channel_state: int | None = None
    channel_mode: int | None = None
    operation_mode: int | None = None
    feed_override: float | None = None
    program: str = ""
    program_number: int | None = None
    program_state: str = ""
    parts: int | None = None
    lights: dict[str, Light] = field(default_factory=dict)
    alarms: dict[str, str] = field(default_factory=dict)  # active alerts, by error code
    message: str = ""  # the last notification that is not an alert
    notifications: int = 0  # data changes and events received (tests, benchmarks)


# ChannelMode words in our model (MTConnect's ControllerMode); the rest keep their own name.
_MODES = {
    ChannelMode.AUTOMATIC: "AUTOMATIC",
    ChannelMode.MDA_MDI: "MANUAL_DATA_INPUT",
    ChannelMode.JOG_MANUAL: "MANUAL",
    ChannelMode.JOG_INCREMENT: "MANUAL",
}
_OPERATION_MODES = {
    MachineOperationMode.AUTOMATIC: "AUTOMATIC",
    MachineOperationMode.MANUAL: "MANUAL",
}
_PROGRAM_EXECUTION = {
    ProgramState.RUNNING: "ACTIVE",
    ProgramState.INTERRUPTED: "INTERRUPTED",
    ProgramState.ENDED: "PROGRAM_COMPLETED",
    ProgramState.ABORTED: "STOPPED",
    ProgramState.INITIALIZING: "READY",
}


def _execution(readings: Readings) -> str:
    """The execution word: the channel's state first (what the control does now), the
    program's state where it says more (a program that ended), the program's state alone
    where the server has no channel."""
    state = readings.channel_state
    if state == ChannelState.ACTIVE:
        return "ACTIVE"
    if state == ChannelState.INTERRUPTED:
        return "INTERRUPTED"
    if state == ChannelState.RESET:
        return "PROGRAM_COMPLETED" if readings.program_state == ProgramState.ENDED else "READY"
    return _PROGRAM_EXECUTION.get(readings.program_state, "UNAVAILABLE")


def _mode(readings: Readings) -> tuple[str, str]:
    """Our mode word and the server's own word beside it where ours has none."""
    if readings.channel_mode is not None:
        try:
            native = ChannelMode(readings.channel_mode)
        except ValueError:
            return "", str(readings.channel_mode)
        mode = _MODES.get(native, "")
        return mode, "" if mode else native.name
    if readings.operation_mode is not None:
        try:
            operation = MachineOperationMode(readings.operation_mode)
        except ValueError:
            return "", str(readings.operation_mode)
        mode = _OPERATION_MODES.get(operation, "")
        return mode, "" if mode else operation.name
    return "", ""


def machine_status(readings: Readings) -> MachineStatus:
    """The status for what the server reported; every active alert is an error."""
    mode, native = _mode(readings)
    overrides = {} if readings.feed_override is None else {"feed": float(readings.feed_override)}
    return MachineStatus(
        at=utcnow(),
        available=True,
        execution=_execution(readings),
        mode=mode,
        native_mode=native,
        program=readings.program,
        part_count=readings.parts,
        overrides=overrides,
        errors=tuple(readings.alarms.values()),
        message=readings.message,
    )


def _int(value: Any) -> int | None:
    return int(value) if isinstance(value, int | float) and not isinstance(value, bool) else None


def _text(value: Any) -> str:
    if isinstance(value, ua.LocalizedText):
        return value.Text or ""
    return "" if value is None else str(value)


class _Handler:
    """asyncua's subscription handler: routes each notification to its setter."""

    def __init__(self, readings: Readings) -> None:
        self.readings = readings
        self.setters: dict[ua.NodeId, Callable[[Any], None]] = {}

    def datachange_notification(self, node: Node, val: Any, data: Any) -> None:
        setter = self.setters.get(node.nodeid)
        if setter is not None:
            setter(val)
            self.readings.notifications += 1

    def event_notification(self, event: Any) -> None:
        fields = vars(event)
        code = fields.get("ErrorCode")
        text = _text(fields.get("Message"))
        active = fields.get("ActiveState/Id")
        self.readings.notifications += 1
        if code is None and active is None:
            self.readings.message = text  # a notification, not an alert
            return
        key = str(code) if code not in (None, "") else text
        if active is False:
            self.readings.alarms.pop(key, None)
        else:
            self.readings.alarms[key] = f"{code} {text}".strip() if code else text

    def status_change_notification(self, status: Any) -> None:
        log.info("subscription status: %s", status)


class OpcuaConnector(StatusOnly):
    """One machine object of an OPC UA server, subscribed while the link is up."""

    through = "OPC UA here"

    config: OpcuaMachine

    def __init__(self, config: OpcuaMachine) -> None:
        self.config = config
        self._client: Client | None = None
        self._subscription: Subscription | None = None
        self._lost: Exception | None = None
        self.readings = Readings()
        self.sessions = 0  # sessions opened (a reconnect opens one more)
        self.security_policy_uri = ""  # the policy of the last session opened

    async def connect(self) -> None:
        """Open a session, find the machine, subscribe to its values and alerts."""
        config = self.config
        self._lost = None
        self.readings = Readings()
        client = Client(
            config.endpoint, timeout=config.request_timeout, watchdog_intervall=config.watchdog
        )
        client.application_uri = config.application_uri
        client.connection_lost_callback = self._on_lost
        if config.user:
            client.set_user(config.user)
            client.set_password(config.password)
        self._client = client
        try:
            async with asyncio.timeout(config.request_timeout * 3):
                if config.security_policy == "Basic256Sha256":
                    await self._secure(client)
                await client.connect()
                self.sessions += 1
                self.security_policy_uri = client.security_policy.URI
                machine = await self._machine(client)
                await self._subscribe(client, machine)
        except TimeoutError:
            raise TransportError(f"{config.name}: {config.endpoint} did not answer") from None
        except (OSError, UaError, ConnectionError) as exc:
            raise TransportError(f"{config.name}: {config.endpoint}: {exc}") from None

    async def _secure(self, client: Client) -> None:
        config = self.config
        for key in ("certificate", "private_key"):
            if not Path(getattr(config, key)).is_file():
                raise InputError(f"{config.name}: {key} {getattr(config, key)!r} is not a file")
        mode = getattr(ua.MessageSecurityMode, config.security_mode)
        await client.set_security(
            SecurityPolicyBasic256Sha256,
            certificate=config.certificate,
            private_key=config.private_key,
            server_certificate=config.server_certificate or None,
            mode=mode,
        )

    async def _on_lost(self, exc: Exception) -> None:
        log.info("%s: session lost: %r", self.config.name, exc)
        self._lost = exc

    async def _machine(self, client: Client) -> Node:
        """The machine object: by node id, or by browse names from the Root folder."""
        config = self.config
        if config.machine_node:
            return client.get_node(config.machine_node)
        node = client.nodes.root
        for name in (part for part in config.browse_root.split("/") if part):
            found = await _child(node, name)
            if found is None:
                raise TransportError(f"{config.name}: the server has no {config.browse_root!r}")
            node = found
        if config.machine:
            found = await _child(node, config.machine)
            if found is None:
                raise TransportError(
                    f"{config.name}: no machine {config.machine!r} in {config.browse_root!r}"
                )
            return found
        for description in await node.get_children_descriptions():
            candidate = client.get_node(description.NodeId)
            names = {d.BrowseName.Name for d in await candidate.get_children_descriptions()}
            if {"Monitoring", "Production"} <= names:
                return candidate
        raise TransportError(f"{config.name}: no machine tool object in {config.browse_root!r}")

    async def _subscribe(self, client: Client, machine: Node) -> None:
        readings = self.readings
        handler = _Handler(readings)
        items: list[tuple[Node, Callable[[Any], None]]] = []

        async def watch(
            path: tuple[str, ...], setter: Callable[[Any], None], base: Node = machine
        ) -> None:
            node = await _path(base, path)
            if node is not None:
                items.append((node, setter))

        def put(name: str, convert: Callable[[Any], Any]) -> Callable[[Any], None]:
            return lambda value: setattr(readings, name, convert(value))

        await watch(Paths.OPERATION_MODE, put("operation_mode", _int))
        await watch(Paths.PROGRAM_NAME, put("program", _text))
        await watch(Paths.PROGRAM_NUMBER, put("program_number", _int))
        await watch(Paths.PROGRAM_STATE, put("program_state", _text))
        await watch(Paths.PARTS, put("parts", _int))
        channel = await self._channel(machine)
        if channel is not None:
            await watch((Paths.CHANNEL_STATE,), put("channel_state", _int), channel)
            await watch((Paths.CHANNEL_MODE,), put("channel_mode", _int), channel)
            await watch((Paths.FEED_OVERRIDE,), put("feed_override", _float), channel)
        stacklight = await _path(machine, Paths.STACKLIGHT)
        if stacklight is not None:
            for element in await stacklight.get_children_descriptions():
                name = element.BrowseName.Name
                node = client.get_node(element.NodeId)
                readings.lights[name] = light = Light()
                on = await _child(node, Paths.SIGNAL_ON)
                color = await _child(node, Paths.SIGNAL_COLOR)
                if on is not None:
                    items.append((on, _setter(light, "on", bool)))
                if color is not None:
                    items.append((color, _setter(light, "color", _int)))
        seconds = self.config.publishing_interval
        subscription = await client.create_subscription(seconds * 1000, handler)
        self._subscription = subscription
        for node, setter in items:
            handler.setters[node.nodeid] = setter
        if items:
            await subscription.subscribe_data_change([node for node, _ in items])
        messages = await _path(machine, Paths.MESSAGES)
        if messages is not None:
            namespace = await _namespace(client, self.config.namespace)
            await subscription.subscribe_events(
                messages, ObjectIds.BaseEventType, evfilter=_alert_filter(namespace)
            )

    async def _channel(self, machine: Node) -> Node | None:
        """The channel read for state and mode: the one configured, or the first child of
        ``Monitoring`` that has a ``ChannelState``."""
        monitoring = await _path(machine, Paths.MONITORING)
        if monitoring is None:
            return None
        if self.config.channel:
            return await _child(monitoring, self.config.channel)
        for description in await monitoring.get_children_descriptions():
            node = Node(machine.session, description.NodeId)
            if await _child(node, Paths.CHANNEL_STATE) is not None:
                return node
        return None

    async def close(self) -> None:
        """End the session (or just the socket, when the server has gone)."""
        client, self._client = self._client, None
        self._subscription = None
        if client is None:
            return
        if self._lost is not None:
            client.disconnect_socket()
            return
        try:
            async with asyncio.timeout(self.config.request_timeout):
                await client.disconnect()
        except (TimeoutError, OSError, UaError, ConnectionError):
            client.disconnect_socket()

    async def status(self) -> MachineStatus:
        """The latest values the subscription brought; raises when the session is lost."""
        if self._client is None:
            raise TransportError(f"{self.config.name}: not connected")
        if self._lost is not None:
            raise TransportError(f"{self.config.name}: the OPC UA session was lost: {self._lost}")
        return machine_status(self.readings)


def _setter(light: Light, name: str, convert: Callable[[Any], Any]) -> Callable[[Any], None]:
    def put(value: Any) -> None:
        setattr(light, name, convert(value))

    return put


def _float(value: Any) -> float | None:
    return float(value) if isinstance(value, int | float) and not isinstance(value, bool) else None


async def _child(node: Node, name: str) -> Node | None:
    """The child of ``node`` whose browse name is ``name`` (in whatever namespace)."""
    for description in await node.get_children_descriptions():
        if description.BrowseName.Name == name:
            return Node(node.session, description.NodeId)
    return None


async def _path(node: Node, names: tuple[str, ...]) -> Node | None:
    """The node at ``names`` below ``node``; None where one is missing (an optional part)."""
    found: Node | None = node
    for name in names:
        if found is None:
            return None
        found = await _child(found, name)
    return found


async def _namespace(client: Client, uri: str) -> int:
    try:
        return int(await client.get_namespace_index(uri))
    except ValueError:
        return 0  # not on this server: the ErrorCode field is then looked for in namespace 0


def _alert_filter(namespace: int) -> ua.EventFilter:
    """The fields read of each event: its message and severity, an alert's ErrorCode (OPC
    40501-1 AlertType) and whether the alert is active (AlarmConditionType ActiveState/Id)."""

    def operand(type_id: int, *path: tuple[int, str]) -> ua.SimpleAttributeOperand:
        op = ua.SimpleAttributeOperand()
        op.TypeDefinitionId = ua.NodeId(ua.Int32(type_id))
        op.BrowsePath = [ua.QualifiedName(name, index) for index, name in path]
        op.AttributeId = AttributeIds.Value
        return op

    event_filter = ua.EventFilter()
    event_filter.SelectClauses = [
        operand(ObjectIds.BaseEventType, (0, "Message")),
        operand(ObjectIds.BaseEventType, (0, "Severity")),
        operand(ObjectIds.BaseEventType, (namespace, "ErrorCode")),
        operand(ObjectIds.AlarmConditionType, (0, "ActiveState"), (0, "Id")),
    ]
    return event_filter
