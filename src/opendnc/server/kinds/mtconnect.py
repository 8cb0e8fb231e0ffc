"""Machines that already talk MTConnect: the server reads one device of an agent (probe, then a
sample stream) and files it like any other machine; it sends nothing to it
(docs/mtconnect-input.md)."""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal

from opendnc.server.configkeys import ConfigError, get_key
from opendnc.server.kinds.base import (
    Capabilities,
    ConnectorHooks,
    KindSpec,
    MachineBase,
    MachineKind,
    schema_keys,
)

if TYPE_CHECKING:
    from opendnc.server.machines.base import Connector

__all__ = ["SPEC", "STATUS_FIELDS", "MtconnectMachine"]

STATUS_FIELDS = frozenset(
    {"execution", "mode", "native_mode", "program", "line", "part_count", "tool", "errors"}
)

_URL = re.compile(r"https?://([^/\s:]+|\[[0-9A-Fa-f:]+\])(:\d{1,5})?(/[^\s?#]*)?")
_DEVICE = re.compile(r"[^/\s?#]{1,128}")


@dataclass(frozen=True, kw_only=True)
class MtconnectMachine(MachineBase):
    """A machine read through an MTConnect agent."""

    kind: Literal[MachineKind.MTCONNECT] = MachineKind.MTCONNECT
    url: str  # the agent: http://host:5000 (a path prefix is kept)
    device: str = ""  # the device's name at the agent; "" when the agent has only one
    streaming: bool = True  # sample?interval= stream; False polls current every poll_interval


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
    from opendnc.server.machines.mtconnect import MtconnectConnector

    return MtconnectConnector(config)


def capabilities(config: MtconnectMachine) -> Capabilities:
    """Status only: an agent is read, never written."""
    return Capabilities(status_fields=STATUS_FIELDS)


SPEC = KindSpec(
    kind=MachineKind.MTCONNECT,
    schema=MtconnectMachine,
    keys=schema_keys(MtconnectMachine),
    parse=parse,
    connector=connector,
    capabilities=capabilities,
    misplaced={},
)
