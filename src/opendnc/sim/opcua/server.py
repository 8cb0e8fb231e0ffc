"""A virtual OPC UA server: asyncua's server on loopback exposing machine tools built after
OPC 40501-1 under ``Objects/Machines``, for tests, the fleet and the demo
(docs/opcua-input.md#the-virtual-server).

The companion specification's nodeset files are not available here, so the machines are not
instances of ``MachineToolType``: they are plain objects and variables with the model's browse
names in its namespace, the enumerations as their integers, and an ``AlertType`` event type
(an AlarmConditionType with ``ErrorCode``) raised on ``Notification/Messages``. A client that
finds nodes by browse name, as ours does, reads them as it reads a real machine's.

:meth:`VirtualOpcuaServer.restart` closes the listening socket and every session and opens
them again on the same port with the same address space: a control whose OPC UA server
restarts keeps its counters.
"""

from __future__ import annotations

import logging
import socket
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from asyncua import ua
from asyncua.common.node import Node
from asyncua.crypto.permission_rules import User, UserRole
from asyncua.server.internal_server import InternalServer
from asyncua.server.server import Server
from asyncua.ua.object_ids import ObjectIds

from opendnc.errors import InputError
from opendnc.opcua.model import (
    MACHINE_TOOL_NS,
    MACHINERY_NS,
    MACHINES_FOLDER,
    ChannelMode,
    ChannelState,
    MachineOperationMode,
    ProgramState,
    SignalColor,
)

__all__ = ["MachineNodes", "VirtualOpcuaServer"]

IA_NS = "http://opcfoundation.org/UA/IA/"
LIGHTS = (SignalColor.RED, SignalColor.YELLOW, SignalColor.GREEN)  # top to bottom

# asyncua logs every session and subscription at INFO and warns of its own defaults
for _name in ("asyncua.server", "asyncua.client", "asyncua.common", "asyncua.uaprotocol"):
    logging.getLogger(_name).setLevel(logging.ERROR)


@dataclass
class MachineNodes:
    """The variables of one virtual machine tool, and its alert event generator."""

    name: str
    operation_mode: Node
    channel_state: Node
    channel_mode: Node
    feed_override: Node
    program: Node
    program_number: Node
    program_state: Node
    parts: Node
    lights: dict[SignalColor, Node]  # each element's SignalOn
    alert: Any  # asyncua EventGenerator of AlertType on Notification/Messages
    active_alarms: dict[str, str] = field(default_factory=dict)  # code -> text


class _Users:
    """One user and password, when the server asks for them (anonymous refused)."""

    def __init__(self, user: str, password: str) -> None:
        self.user, self.password = user, password

    def get_user(
        self,
        iserver: InternalServer,
        username: str | None = None,
        password: str | None = None,
        certificate: Any = None,
    ) -> User | None:
        if username == self.user and password == self.password:
            return User(role=UserRole.User, name=username)
        return None


def free_port(host: str) -> int:
    """A TCP port free on ``host`` now (kept over restarts, so a client finds it again)."""
    with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET) as probe:
        probe.bind((host, 0))
        return int(probe.getsockname()[1])


class VirtualOpcuaServer:
    """Machine tools ``names`` on ``opc.tcp://host:port`` (port 0: a free one).

    ``certificate`` and ``private_key`` (files) add the Basic256Sha256 Sign and
    SignAndEncrypt endpoints beside the unsecured one; ``user`` and ``password`` make the
    server refuse anonymous sessions."""

    def __init__(
        self,
        names: list[str],
        *,
        host: str = "127.0.0.1",
        port: int = 0,
        certificate: Path | None = None,
        private_key: Path | None = None,
        user: str = "",
        password: str = "",
    ) -> None:
        if not names or len(set(names)) != len(names):
            raise InputError("a virtual OPC UA server needs distinct machine names")
        self.names = list(names)
        self.host = host
        self.port = port or free_port(host)
        self.certificate = certificate
        self.private_key = private_key
        self.machines: dict[str, MachineNodes] = {}
        self.restarts = 0
        users = _Users(user, password) if user else None
        self._server = Server(user_manager=users)  # type: ignore[arg-type]
        self._built = False

    @property
    def url(self) -> str:
        """The endpoint a client connects to."""
        where = f"[{self.host}]" if ":" in self.host else self.host
        return f"opc.tcp://{where}:{self.port}"

    async def start(self) -> None:
        """Build the address space (once) and listen."""
        if not self._built:
            await self._build()
            self._built = True
        await self._server.start()

    async def close(self) -> None:
        """Stop listening and drop every session."""
        await self._server.stop()

    async def restart(self) -> None:
        """Stop and start again on the same port; the address space and its values stay."""
        await self._server.stop()
        self.restarts += 1
        await self._server.start()

    async def _build(self) -> None:
        server = self._server
        await server.init()
        server.set_endpoint(self.url + "/")
        server.set_server_name("opendnc virtual OPC UA server")
        await server.set_application_uri("urn:opendnc:sim:opcua")
        policies = [ua.SecurityPolicyType.NoSecurity]
        if self.certificate is not None and self.private_key is not None:
            await server.load_certificate(str(self.certificate))
            await server.load_private_key(str(self.private_key))
            policies += [
                ua.SecurityPolicyType.Basic256Sha256_Sign,
                ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt,
            ]
        server.set_security_policy(policies)
        machinery = await server.register_namespace(MACHINERY_NS)
        tool = await server.register_namespace(MACHINE_TOOL_NS)
        ia = await server.register_namespace(IA_NS)
        alert_type = await server.create_custom_event_type(
            tool,
            "AlertType",
            ObjectIds.AlarmConditionType,
            [("ErrorCode", ua.VariantType.String)],
        )
        folder = await server.nodes.objects.add_folder(machinery, MACHINES_FOLDER)
        for name in self.names:
            self.machines[name] = await _machine(server, folder, name, tool, ia, alert_type)


async def _machine(
    server: Server, folder: Node, name: str, tool: int, ia: int, alert_type: Node
) -> MachineNodes:
    """One machine tool's objects and variables, with their values at power-on."""
    machine = await folder.add_object(tool, name)
    identification = await machine.add_object(tool, "Identification")
    await identification.add_variable(tool, "Manufacturer", ua.LocalizedText("opendnc"))
    await identification.add_variable(tool, "SerialNumber", f"SIM-{name}")
    await identification.add_variable(tool, "ProductInstanceUri", f"urn:opendnc:sim:{name}")
    monitoring = await machine.add_object(tool, "Monitoring")
    overall = await monitoring.add_object(tool, "MachineTool")
    operation_mode = await overall.add_variable(
        tool, "OperationMode", int(MachineOperationMode.AUTOMATIC), ua.VariantType.Int32
    )
    stacklight = await monitoring.add_object(tool, "Stacklight")
    lights = {}
    for place, color in enumerate(LIGHTS):
        element = await stacklight.add_object(ia, f"StackElement{place}")
        await element.add_variable(ia, "NumberInList", place, ua.VariantType.UInt16)
        await element.add_variable(ia, "SignalColor", int(color), ua.VariantType.Int32)
        lights[color] = await element.add_variable(ia, "SignalOn", False)
    channel = await monitoring.add_object(tool, "Channel1")
    channel_state = await channel.add_variable(
        tool, "ChannelState", int(ChannelState.RESET), ua.VariantType.Int32
    )
    channel_mode = await channel.add_variable(
        tool, "ChannelMode", int(ChannelMode.AUTOMATIC), ua.VariantType.Int32
    )
    feed = await channel.add_variable(tool, "FeedOverride", 100.0)
    production = await machine.add_object(tool, "Production")
    active = await production.add_object(tool, "ActiveProgram")
    program = await active.add_variable(tool, "Name", "")
    number = await active.add_variable(tool, "NumberInList", 0, ua.VariantType.UInt16)
    state = await active.add_object(tool, "State")
    current = await state.add_variable(tool, "CurrentState", ua.LocalizedText(ProgramState.ENDED))
    statistics = await production.add_object(tool, "Statistics")
    parts = await statistics.add_variable(tool, "PartsProducedInLifetime", 0, ua.VariantType.UInt64)
    notification = await machine.add_object(tool, "Notification")
    messages = await notification.add_object(tool, "Messages")
    await messages.set_event_notifier([ua.EventNotifier.SubscribeToEvents])
    alert = await server.get_event_generator(alert_type, messages.nodeid)
    return MachineNodes(
        name, operation_mode, channel_state, channel_mode, feed, program, number, current,
        parts, lights, alert,
    )  # fmt: skip
