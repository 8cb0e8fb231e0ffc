"""Machines read through an OPC UA server with the umati machine-tool model (OPC 40501-1).

The connector joins the session open to its server (security and user as configured; one
session per server, shared by every machine on it: :mod:`.session`), finds the machine object
by its browse names, and *subscribes*: monitored items on the session's one subscription, one
per value it maps
(channel state and mode, operation mode, feed override, the active program's name, number and
state, the part count, the stacklight's elements) and an event monitored item on
``Notification/Messages`` for alerts. The server sends what changed; a status poll takes the
latest values held here, so a poll costs no request. What the model says is put into our words
here (:func:`machine_status`) and the one classifier (:func:`opendnc.server.core.state.classify`)
files the machine; the mapping is ours, not the specification's (docs/opcua-input.md#mapping).

A lost session (the server restarted, the network went) makes :meth:`OpcuaConnector.status`
of every machine on it raise: each machine's supervisor closes the link and connects again,
which joins the one new session, browses and subscribes anew (a restarted server may have
given its nodes other ids).
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from asyncua import ua
from asyncua.ua.attribute_ids import AttributeIds
from asyncua.ua.object_ids import ObjectIds
from asyncua.ua.uaerrors import UaError

from opendnc.errors import TransportError
from opendnc.opcua.model import ChannelMode, ChannelState, MachineOperationMode, Paths, ProgramState
from opendnc.server.core.status import MachineStatus
from opendnc.server.kinds.connector import StatusOnly
from opendnc.server.kinds.opcua import session as sessions
from opendnc.server.kinds.opcua.schema import OpcuaMachine
from opendnc.server.kinds.opcua.session import ROOT
from opendnc.server.store.models import utcnow

__all__ = ["Light", "OpcuaConnector", "Readings", "machine_status"]

log = logging.getLogger(__name__)
# asyncua logs a lost server's every failed publish with a traceback, once a second; the loss
# is logged once by the session, with the reason, and the supervisor logs the reconnect
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


class _Alerts:
    """A machine's events (its ``Notification/Messages``): alerts raised and cleared, and
    notifications."""

    def __init__(self, readings: Readings) -> None:
        self.readings = readings

    def __call__(self, event: Any) -> None:
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


class OpcuaConnector(StatusOnly):
    """One machine object of an OPC UA server, subscribed while the link is up."""

    through = "OPC UA here"

    config: OpcuaMachine

    def __init__(self, config: OpcuaMachine) -> None:
        self.config = config
        self._session: sessions.Session | None = None
        self._handles: list[int] = []  # this machine's monitored items on the subscription
        self.readings = Readings()
        self.sessions = 0  # sessions joined (a reconnect joins one more)
        self.security_policy_uri = ""  # the policy of the last session joined

    async def connect(self) -> None:
        """Join the server's session, find the machine, subscribe to its values and alerts."""
        config = self.config
        self.readings = Readings()
        session = await sessions.acquire(config)
        self._session = session
        self.sessions += 1
        self.security_policy_uri = session.security_policy_uri
        try:
            async with session.setting_up, asyncio.timeout(config.request_timeout * 3):
                machine = await self._machine(session)
                await self._subscribe(session, machine)
        except TimeoutError:
            await self.close()
            raise TransportError(f"{config.name}: {config.endpoint} did not answer") from None
        except (OSError, UaError, ConnectionError) as exc:
            await self.close()
            raise TransportError(f"{config.name}: {config.endpoint}: {exc}") from None
        except TransportError:
            await self.close()
            raise

    async def _machine(self, session: sessions.Session) -> ua.NodeId:
        """The machine object: by node id, or by browse names from the Root folder."""
        config = self.config
        if config.machine_node:
            node: ua.NodeId = session.client.get_node(config.machine_node).nodeid
            return node
        if config.machine:
            found = await session.folder_child(config.browse_root, config.machine)
            if found is None:
                raise TransportError(
                    f"{config.name}: no machine {config.machine!r} in {config.browse_root!r}"
                )
            return found
        parts = tuple(part for part in config.browse_root.split("/") if part)
        root = ROOT
        folder = (await session.resolve(root, [parts]))[parts]
        if folder is None:
            raise TransportError(f"{config.name}: the server has no {config.browse_root!r}")
        candidates: list[ua.NodeId] = [d.NodeId for d in (await session.children([folder]))[folder]]
        children = await session.children(candidates)
        for candidate in candidates:
            if {"Monitoring", "Production"} <= {d.BrowseName.Name for d in children[candidate]}:
                return candidate
        raise TransportError(f"{config.name}: no machine tool object in {config.browse_root!r}")

    async def _subscribe(self, session: sessions.Session, machine: ua.NodeId) -> None:
        readings = self.readings
        items: list[tuple[ua.NodeId, Callable[[Any], None]]] = []

        def put(name: str, convert: Callable[[Any], Any]) -> Callable[[Any], None]:
            def setter(value: Any) -> None:
                setattr(readings, name, convert(value))
                readings.notifications += 1

            return setter

        wanted: dict[tuple[str, ...], Callable[[Any], None]] = {
            Paths.OPERATION_MODE: put("operation_mode", _int),
            Paths.PROGRAM_NAME: put("program", _text),
            Paths.PROGRAM_NUMBER: put("program_number", _int),
            Paths.PROGRAM_STATE: put("program_state", _text),
            Paths.PARTS: put("parts", _int),
        }
        found = await session.resolve(
            machine, [*wanted, Paths.MONITORING, Paths.STACKLIGHT, Paths.MESSAGES]
        )
        items += [(node, wanted[path]) for path, node in found.items() if path in wanted and node]
        channel = await self._channel(session, found[Paths.MONITORING])
        if channel is not None:
            named = await session.resolve(
                channel, [(Paths.CHANNEL_STATE,), (Paths.CHANNEL_MODE,), (Paths.FEED_OVERRIDE,)]
            )
            setters: dict[tuple[str, ...], Callable[[Any], None]] = {
                (Paths.CHANNEL_STATE,): put("channel_state", _int),
                (Paths.CHANNEL_MODE,): put("channel_mode", _int),
                (Paths.FEED_OVERRIDE,): put("feed_override", _float),
            }
            items += [(node, setters[path]) for path, node in named.items() if node is not None]
        stacklight = found[Paths.STACKLIGHT]
        if stacklight is not None:
            elements = (await session.children([stacklight]))[stacklight]
            signals = await session.children(e.NodeId for e in elements)
            for element in elements:
                readings.lights[element.BrowseName.Name] = light = Light()
                for child in signals[element.NodeId]:
                    if child.BrowseName.Name == Paths.SIGNAL_ON:
                        items.append((child.NodeId, _setter(readings, light, "on", bool)))
                    elif child.BrowseName.Name == Paths.SIGNAL_COLOR:
                        items.append((child.NodeId, _setter(readings, light, "color", _int)))
        subscription = await session.ensure_subscription()
        router = session.router
        if items:
            nodes = [session.client.get_node(node) for node, _ in items]
            handles = await subscription.subscribe_data_change(nodes)
            for handle, (_, setter) in zip(handles, items, strict=True):
                if isinstance(handle, int):
                    router.values[handle] = setter
                    self._handles.append(handle)
        messages = found[Paths.MESSAGES]
        if messages is not None:
            namespace = await session.namespace(self.config.namespace)
            handle = await subscription.subscribe_events(
                session.client.get_node(messages),
                ObjectIds.BaseEventType,
                evfilter=_alert_filter(namespace),
            )
            router.events[handle] = _Alerts(readings)
            self._handles.append(handle)

    async def _channel(
        self, session: sessions.Session, monitoring: ua.NodeId | None
    ) -> ua.NodeId | None:
        """The channel read for state and mode: the one configured, or the first child of
        ``Monitoring`` that has a ``ChannelState``."""
        if monitoring is None:
            return None
        children = (await session.children([monitoring]))[monitoring]
        if self.config.channel:
            return next(
                (d.NodeId for d in children if d.BrowseName.Name == self.config.channel), None
            )
        grandchildren = await session.children(d.NodeId for d in children)
        for description in children:
            names = {d.BrowseName.Name for d in grandchildren[description.NodeId]}
            if Paths.CHANNEL_STATE in names:
                node: ua.NodeId = description.NodeId
                return node
        return None

    async def close(self) -> None:
        """Leave the session: this machine's items go, the session with its last machine."""
        session, self._session = self._session, None
        handles, self._handles = self._handles, []
        if session is None:
            return
        for handle in handles:
            session.router.values.pop(handle, None)
            session.router.events.pop(handle, None)
        if handles and session.users > 1 and session.lost is None and session.subscription:
            # others stay on the session: this machine's items must not go on costing
            try:
                async with asyncio.timeout(self.config.request_timeout):
                    await session.subscription.unsubscribe(handles)
            except (TimeoutError, OSError, UaError, ConnectionError) as exc:
                log.info("%s: items not removed: %r", self.config.name, exc)
        await sessions.release(session)

    async def status(self) -> MachineStatus:
        """The latest values the subscription brought; raises when the session is lost."""
        session = self._session
        if session is None:
            raise TransportError(f"{self.config.name}: not connected")
        if session.lost is not None:
            raise TransportError(f"{self.config.name}: the OPC UA session was lost: {session.lost}")
        return machine_status(self.readings)


def _setter(
    readings: Readings, light: Light, name: str, convert: Callable[[Any], Any]
) -> Callable[[Any], None]:
    def put(value: Any) -> None:
        setattr(light, name, convert(value))
        readings.notifications += 1

    return put


def _float(value: Any) -> float | None:
    return float(value) if isinstance(value, int | float) and not isinstance(value, bool) else None


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
