"""The one table of machine kinds, and what generic code asks of a configured machine.

Each kind is a package (``kinds/<kind>/``) exporting a :class:`KindSpec`; :data:`KINDS` maps
the ``kind`` key of the configuration to it, one line per kind. Generic code asks the spec
(:func:`spec_of`, :func:`capabilities_of`, :func:`connector_for`, the hooks) and never a
concrete class. Adding a kind is a new package and one line here; :func:`register` adds one
at run time (a test's own kind). docs/server.md#shape-components-and-kinds.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable
from typing import TYPE_CHECKING, Any

from opendnc.errors import InputError
from opendnc.nccheck.limits import Envelope, LimitsError, parse_envelope
from opendnc.server.core.configkeys import NAME, ConfigError, get_key, known_keys
from opendnc.server.kinds.base import (
    COMMON_KEYS,
    Capabilities,
    ConnectorHooks,
    DprntSource,
    KindSpec,
    MachineConfig,
    ReceiveFolder,
    SharedMachine,
)
from opendnc.server.kinds.filedrop import capabilities_with, receive_of, with_files
from opendnc.server.kinds.filedrop_config import parse_files
from opendnc.server.kinds.haas_ngc import spec as haas_ngc
from opendnc.server.kinds.haas_serial import spec as haas_serial
from opendnc.server.kinds.lsv2 import spec as lsv2
from opendnc.server.kinds.mtconnect import spec as mtconnect
from opendnc.server.kinds.opcua import spec as opcua
from opendnc.server.kinds.serial import spec as serial

if TYPE_CHECKING:
    from opendnc.server.kinds.connector import Connector

__all__ = [
    "KINDS",
    "MachineConfig",
    "capabilities_of",
    "connector_for",
    "dprnt_of",
    "label_of",
    "parse_machine",
    "program_folder_of",
    "receive_folder_of",
    "register",
    "shares_of",
    "spec_of",
]

log = logging.getLogger(__name__)

KINDS: dict[str, KindSpec[Any]] = {
    lsv2.SPEC.kind: lsv2.SPEC,
    haas_ngc.SPEC.kind: haas_ngc.SPEC,
    haas_serial.SPEC.kind: haas_serial.SPEC,
    mtconnect.SPEC.kind: mtconnect.SPEC,
    opcua.SPEC.kind: opcua.SPEC,
    serial.SPEC.kind: serial.SPEC,
}
"""Every kind the server knows, by its ``kind`` key: one line per kind."""


def register(spec: KindSpec[Any]) -> None:
    """Add ``spec`` to the table (a kind defined outside this package, e.g. by a test).
    A key that is taken is refused: a kind's key is stored in configurations and the
    database, so two kinds must never share one."""
    if spec.kind in KINDS and KINDS[spec.kind] is not spec:
        raise InputError(f"a machine kind {spec.kind!r} is already registered")
    KINDS[spec.kind] = spec


def spec_of(machine: MachineConfig | str) -> KindSpec[Any]:
    """The spec of ``machine``'s kind (or of the kind named by its key)."""
    return KINDS[machine if isinstance(machine, str) else machine.kind]


def label_of(kind: str) -> str:
    """What pages call a kind (its key if no kind has it: a machine of an older file)."""
    spec = KINDS.get(kind)
    return spec.label if spec is not None else kind


def capabilities_of(machine: MachineConfig) -> Capabilities:
    """What ``machine`` can do as configured (its kind, its opt-ins, its files table)."""
    return capabilities_with(spec_of(machine).capabilities(machine), machine)


def connector_for(machine: MachineConfig, hooks: ConnectorHooks | None = None) -> Connector:
    """The connector that reaches ``machine``'s control (its programs through its folder
    where it has a files table: docs/files.md)."""
    return with_files(spec_of(machine).connector(machine, hooks or ConnectorHooks()), machine)


def dprnt_of(machine: MachineConfig) -> DprntSource | None:
    """Where ``machine`` prints DPRNT lines; None if nowhere."""
    return spec_of(machine).dprnt(machine)


def receive_folder_of(machine: MachineConfig) -> ReceiveFolder | None:
    """The folder on ``machine``'s control that is collected into the inbox; None if none
    (a files table that receives before the kind's own folder)."""
    return receive_of(machine) or spec_of(machine).receive_folder(machine)


def program_folder_of(machine: MachineConfig) -> str:
    """Where the file browser opens on ``machine``'s control (``""``: it has none)."""
    return spec_of(machine).program_folder(machine)


def shares_of(machines: Iterable[MachineConfig]) -> dict[str, SharedMachine]:
    """The machines with a network share (for the net share), by name, in order."""
    found = ((m, spec_of(m).share(m)) for m in machines)
    return {m.name: SharedMachine(m, share) for m, share in found if share}


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
    kind = get_key(raw, prefix, "kind", str, "")
    spec = KINDS.get(kind)
    if spec is None:
        raise ConfigError(f"{prefix}.kind", f"expected one of {', '.join(KINDS)}")
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
            owners = " and ".join(sorted(s.kind for s in KINDS.values() if key in s.keys))
            log.warning("%s.%s: only for %s; ignored for a %s", prefix, key, owners, kind)
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
        "files": parse_files(raw.get("files"), f"{prefix}.files", name),
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
