"""Machines that already talk MTConnect: the server reads one device of an agent (probe, then a
sample stream) and files it like any other machine; it sends nothing to it
(docs/mtconnect-input.md)."""

from __future__ import annotations

import re
from typing import Any

from opendnc.server.core.configkeys import ConfigError, get_key
from opendnc.server.kinds.base import (
    Capabilities,
    ConnectorHooks,
    KindSpec,
    schema_keys,
)
from opendnc.server.kinds.connector import Connector
from opendnc.server.kinds.mtconnect.schema import MtconnectMachine

__all__ = ["SPEC", "STATUS_FIELDS", "MtconnectMachine"]

STATUS_FIELDS = frozenset(
    {"execution", "mode", "native_mode", "program", "line", "part_count", "tool", "errors"}
)

_URL = re.compile(r"https?://([^/\s:]+|\[[0-9A-Fa-f:]+\])(:\d{1,5})?(/[^\s?#]*)?")
_DEVICE = re.compile(r"[^/\s?#]{1,128}")


def parse(raw: dict[str, Any], prefix: str, common: dict[str, Any]) -> MtconnectMachine:
    """An ``mtconnect`` machine's own keys."""
    url = get_key(raw, prefix, "url", str, "")
    if not _URL.fullmatch(url):
        raise ConfigError(f"{prefix}.url", "expected the agent's address, http://HOST:PORT")
    device = get_key(raw, prefix, "device", str, "")
    if device and not _DEVICE.fullmatch(device):
        raise ConfigError(f"{prefix}.device", "expected the device's name at the agent")
    return MtconnectMachine(
        **common,
        url=url.rstrip("/"),
        device=device,
        streaming=get_key(raw, prefix, "streaming", bool, True),
    )


def connector(config: MtconnectMachine, hooks: ConnectorHooks) -> Connector:
    """The agent reader."""
    # imported here, not at the top: a server imports every kind but needs only the
    # connectors of the kinds it has machines of (docs/server.md#shape-components-and-kinds)
    from opendnc.server.kinds.mtconnect.connector import MtconnectConnector

    return MtconnectConnector(config)


def capabilities(config: MtconnectMachine) -> Capabilities:
    """Status only: an agent is read, never written."""
    return Capabilities(status_fields=STATUS_FIELDS)


SPEC = KindSpec(
    kind="mtconnect",
    label="MTConnect agent",
    schema=MtconnectMachine,
    keys=schema_keys(MtconnectMachine),
    parse=parse,
    connector=connector,
    capabilities=capabilities,
)
