"""Machine kinds: one module per kind, each owning its configuration schema, its connector
factory and its capabilities (docs/server.md#shape-components-and-kinds).

:data:`MachineConfig` is the union of the kinds' schemas, told apart by ``kind``; code that
needs a kind's own field narrows on ``machine.kind`` (or asks :func:`capabilities_of`, which is
what pages, actions and the runner do). Adding a kind is a new module with a :class:`KindSpec`
and one line in :data:`KINDS`.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Any, cast

from opendnc.nccheck.limits import Envelope, LimitsError, parse_envelope
from opendnc.server.configkeys import NAME, ConfigError, get_key, known_keys
from opendnc.server.kinds import haas_ngc, haas_serial, lsv2, mtconnect, serial
from opendnc.server.kinds.base import (
    COMMON_KEYS,
    LSV2_SERIAL,
    Capabilities,
    ConnectorHooks,
    KindSpec,
    MachineBase,
    MachineKind,
    SerialProfile,
)
from opendnc.server.kinds.haas_ngc import HaasNgcMachine
from opendnc.server.kinds.haas_serial import HaasSerialMachine
from opendnc.server.kinds.lsv2 import Lsv2Machine
from opendnc.server.kinds.mtconnect import MtconnectMachine
from opendnc.server.kinds.serial import SerialMachine

if TYPE_CHECKING:
    from opendnc.server.machines.base import Connector

__all__ = [
    "KINDS",
    "LSV2_SERIAL",
    "Capabilities",
    "ConnectorHooks",
    "HaasNgcMachine",
    "HaasSerialMachine",
    "KindSpec",
    "Lsv2Machine",
    "MachineBase",
    "MachineConfig",
    "MachineKind",
    "MtconnectMachine",
    "SerialMachine",
    "SerialProfile",
    "capabilities_of",
    "connector_for",
    "parse_machine",
    "spec_of",
]

log = logging.getLogger(__name__)

MachineConfig = Lsv2Machine | HaasNgcMachine | HaasSerialMachine | MtconnectMachine | SerialMachine
"""One machine of the shop: a discriminated union on ``kind``."""

KINDS: dict[MachineKind, KindSpec[Any]] = {
    MachineKind.LSV2: lsv2.SPEC,
    MachineKind.HAAS_NGC: haas_ngc.SPEC,
    MachineKind.HAAS_SERIAL: haas_serial.SPEC,
    MachineKind.MTCONNECT: mtconnect.SPEC,
    MachineKind.SERIAL: serial.SPEC,
}


def spec_of(machine: MachineBase | MachineKind) -> KindSpec[Any]:
    """The kind module's spec for ``machine`` (or for a kind)."""
    kind = machine if isinstance(machine, MachineKind) else cast(MachineConfig, machine).kind
    return KINDS[kind]


def capabilities_of(machine: MachineConfig) -> Capabilities:
    """What ``machine`` can do as configured (its kind and its opt-ins)."""
    return spec_of(machine).capabilities(machine)


def connector_for(machine: MachineConfig, hooks: ConnectorHooks | None = None) -> Connector:
    """The connector that reaches ``machine``'s control."""
    return spec_of(machine).connector(machine, hooks or ConnectorHooks())


def _empty(value: object) -> bool:
    return value in ("", 0, False) and not isinstance(value, float | dict)


def _envelope(raw: dict[str, Any], prefix: str) -> Envelope | None:
    try:
        return parse_envelope(raw, prefix)  # program checks: opendnc.nccheck.limits
    except LimitsError as exc:
        raise ConfigError(exc.key, exc.problem) from None


def parse_machine(raw: object, prefix: str) -> MachineConfig:
    """One ``[[machines]]`` table; :class:`ConfigError` names the first bad key."""
    if not isinstance(raw, dict):
        raise ConfigError(prefix, "expected a table")
    others = set().union(*(spec.keys for spec in KINDS.values()))
    known_keys(raw, prefix, COMMON_KEYS | others)
    if "name" not in raw:
        raise ConfigError(f"{prefix}.name", "missing")
    name = get_key(raw, prefix, "name", str, "")
    if not NAME.fullmatch(name):
        raise ConfigError(f"{prefix}.name", "use letters, digits, '-', '_' or '.' (at most 64)")
    kind_text = get_key(raw, prefix, "kind", str, "")
    try:
        kind = MachineKind(kind_text)
    except ValueError:
        choices = ", ".join(k.value for k in MachineKind)
        raise ConfigError(f"{prefix}.kind", f"expected one of {choices}") from None
    spec = KINDS[kind]
    own = {key: value for key, value in raw.items() if key in COMMON_KEYS | spec.keys}
    for key, value in raw.items():
        if key in own:
            continue
        # A key of another kind. The flat schema of earlier versions took every key for every
        # kind and refused only a few (a drip-feed on a TNC): those are refused still, with
        # the reason; the rest meant nothing for this kind and are passed over with a warning,
        # so files written then keep working.
        reason = next((s.misplaced[key] for s in KINDS.values() if key in s.misplaced), "")
        if reason and not _empty(value):
            raise ConfigError(f"{prefix}.{key}", reason)
        if not _empty(value):
            owners = " and ".join(sorted(s.kind.value for s in KINDS.values() if key in s.keys))
            log.warning("%s.%s: only for %s; ignored for a %s", prefix, key, owners, kind.value)
    poll = get_key(raw, prefix, "poll_interval", float, 1.0)
    if not 0.05 <= poll <= 3600:
        raise ConfigError(f"{prefix}.poll_interval", "expected seconds between 0.05 and 3600")
    common = {
        "name": name,
        "released_only": get_key(raw, prefix, "released_only", bool, False),
        "poll_interval": poll,
        "description": get_key(raw, prefix, "description", str, ""),
        "envelope": _envelope(raw, prefix),
        "servers": _servers(raw, prefix),
    }
    machine: MachineConfig = spec.parse(own, prefix, common)
    return machine


def _servers(raw: dict[str, Any], prefix: str) -> tuple[str, ...]:
    """``servers = ["dnc-1"]``: the servers of a cluster that may serve the machine (the one
    host its serial port is on); empty, any of them (docs/server.md#several-servers)."""
    value = raw.get("servers", [])
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise ConfigError(f"{prefix}.servers", 'expected a list of server names: ["dnc-1"]')
    for name in value:
        if not NAME.fullmatch(name):
            raise ConfigError(f"{prefix}.servers", f"{name!r} is not a server name")
    return tuple(dict.fromkeys(value))
