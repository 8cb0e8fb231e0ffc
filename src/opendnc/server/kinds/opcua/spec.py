"""Machines that speak OPC UA (umati, OPC 40501-1): the server subscribes to one machine
object of a control's OPC UA server and files it like any other machine; it sends nothing to
it (docs/opcua-input.md)."""

from __future__ import annotations

import re
from typing import Any

from opendnc.server.core.configkeys import ConfigError, get_key
from opendnc.server.kinds.base import Capabilities, ConnectorHooks, KindSpec, schema_keys
from opendnc.server.kinds.connector import Connector
from opendnc.server.kinds.opcua.schema import SECURITY_MODES, SECURITY_POLICIES, OpcuaMachine

__all__ = ["SPEC", "STATUS_FIELDS", "OpcuaMachine"]

STATUS_FIELDS = frozenset(
    {"execution", "mode", "native_mode", "program", "part_count", "overrides", "errors"}
)

_ENDPOINT = re.compile(r"opc\.tcp://([^/\s:]+|\[[0-9A-Fa-f:]+\])(:\d{1,5})?(/[^\s?#]*)?")
_NODE_ID = re.compile(r"(ns=\d+|nsu=[^;]+);[isgb]=.+")
_NAME = re.compile(r"[^/\s][^/]{0,127}")


def parse(raw: dict[str, Any], prefix: str, common: dict[str, Any]) -> OpcuaMachine:
    """An ``opcua`` machine's own keys."""

    def text(key: str, default: str = "") -> str:
        value: str = get_key(raw, prefix, key, str, default)
        return value

    endpoint = text("endpoint")
    if not _ENDPOINT.fullmatch(endpoint):
        raise ConfigError(
            f"{prefix}.endpoint", "expected the server's address, opc.tcp://HOST:PORT"
        )
    machine = text("machine")
    if machine and not _NAME.fullmatch(machine):
        raise ConfigError(f"{prefix}.machine", "expected the machine object's browse name")
    root = text("browse_root", OpcuaMachine.browse_root)
    if not all(_NAME.fullmatch(part) for part in root.split("/")):
        raise ConfigError(f"{prefix}.browse_root", 'expected browse names: "Objects/Machines"')
    node = text("machine_node")
    if node and not _NODE_ID.fullmatch(node):
        raise ConfigError(f"{prefix}.machine_node", 'expected a node id: "ns=3;i=5001"')
    policy = text("security_policy", "None")
    if policy not in SECURITY_POLICIES:
        raise ConfigError(f"{prefix}.security_policy", f"expected {' or '.join(SECURITY_POLICIES)}")
    mode = text("security_mode", OpcuaMachine.security_mode)
    if mode not in SECURITY_MODES:
        raise ConfigError(f"{prefix}.security_mode", f"expected {' or '.join(SECURITY_MODES)}")
    certificate, key = text("certificate"), text("private_key")
    if policy != "None" and not (certificate and key):
        raise ConfigError(
            f"{prefix}.certificate", f"{policy} needs certificate and private_key (file paths)"
        )
    if "password" in raw and not isinstance(raw["password"], str):
        raise ConfigError(f"{prefix}.password", "expected a string")  # never echo its value
    user, password = text("user"), str(raw.get("password", ""))
    if password and not user:
        raise ConfigError(f"{prefix}.password", "a password needs a user")
    seconds = {}
    for name, low, high in (
        ("publishing_interval", 0.01, 60.0),
        ("request_timeout", 0.1, 600.0),
        ("watchdog", 0.1, 600.0),
    ):
        value = get_key(raw, prefix, name, float, getattr(OpcuaMachine, name))
        if not low <= value <= high:
            raise ConfigError(f"{prefix}.{name}", f"expected seconds between {low} and {high}")
        seconds[name] = value
    return OpcuaMachine(
        **common,
        endpoint=endpoint,
        machine=machine,
        browse_root=root,
        machine_node=node,
        namespace=text("namespace", OpcuaMachine.namespace),
        channel=text("channel"),
        security_policy=policy,
        security_mode=mode,
        certificate=certificate,
        private_key=key,
        server_certificate=text("server_certificate"),
        application_uri=text("application_uri", OpcuaMachine.application_uri),
        user=user,
        password=password,
        **seconds,
    )


def connector(config: OpcuaMachine, hooks: ConnectorHooks) -> Connector:
    """The subscription to the machine object."""
    # imported here: asyncua takes a while to import, and only servers with such a machine
    # need it
    from opendnc.server.kinds.opcua.connector import OpcuaConnector

    return OpcuaConnector(config)


def capabilities(config: OpcuaMachine) -> Capabilities:
    """Status only: the machine is read, never written."""
    return Capabilities(status_fields=STATUS_FIELDS)


SPEC = KindSpec(
    kind="opcua",
    label="OPC UA (umati)",
    schema=OpcuaMachine,
    keys=schema_keys(OpcuaMachine),
    parse=parse,
    connector=connector,
    capabilities=capabilities,
)
