"""Haas controls on RS-232 (XModem or plain text, drip-feed, MDC and DPRNT on the same port):
schema, connector, what they can do."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal

from opendnc.server.configkeys import ConfigError, get_key, table_at
from opendnc.server.kinds.base import (
    Capabilities,
    ConnectorHooks,
    KindSpec,
    MachineBase,
    MachineKind,
    SerialProfile,
    parse_profile,
    schema_keys,
)
from opendnc.server.kinds.haas_ngc import tcp_dprnt

if TYPE_CHECKING:
    from opendnc.server.machines.base import Connector

__all__ = ["MDC_STATUS_FIELDS", "SPEC", "HaasSerialMachine"]

MDC_STATUS_FIELDS = frozenset({"execution", "mode", "native_mode", "program", "part_count"})


@dataclass(frozen=True, kw_only=True)
class HaasSerialMachine(MachineBase):
    """A Haas control on a serial line."""

    kind: Literal[MachineKind.HAAS_SERIAL] = MachineKind.HAAS_SERIAL
    serial: str  # device or URL (socket://, rfc2217://)
    profile: SerialProfile = field(default_factory=SerialProfile)
    dripfeed: bool = False  # drip-feeding runs the program on the machine: an explicit opt-in
    mdc: bool = False  # status by MDC Q-commands on the port (Setting 143 ON)
    mdc_interval: float = 3.0  # least seconds between two MDC status reads
    dprnt: str = ""  # "serial" (the same port) or tcp://HOST:PORT; "" for none


def parse(raw: dict[str, Any], prefix: str, common: dict[str, Any]) -> HaasSerialMachine:
    """A ``haas_serial`` machine's own keys."""
    serial = get_key(raw, prefix, "serial", str, "")
    if not serial:
        raise ConfigError(f"{prefix}.serial", "a serial Haas needs a device or URL")
    # Classic controls have frozen under fast serial polling: 3 s apart by default
    # (docs/haas.md#mdc-polling).
    mdc_interval = get_key(raw, prefix, "mdc_interval", float, 3.0)
    if not 0.05 <= mdc_interval <= 3600:
        raise ConfigError(f"{prefix}.mdc_interval", "expected seconds between 0.05 and 3600")
    dprnt = get_key(raw, prefix, "dprnt", str, "")
    if dprnt != "serial":
        dprnt = tcp_dprnt(dprnt, f"{prefix}.dprnt")
    profile = parse_profile(
        table_at(raw, "serial_profile"), f"{prefix}.serial_profile", SerialProfile()
    )
    if dprnt == "serial" and profile.protocol == "text":
        # Printed lines and a punched program are both plain text on the one port.
        raise ConfigError(
            f"{prefix}.dprnt",
            'serial DPRNT needs protocol = "xmodem" (a text '
            "punch and a printed line cannot be told apart)",
        )
    return HaasSerialMachine(
        **common,
        serial=serial,
        profile=profile,
        dripfeed=get_key(raw, prefix, "dripfeed", bool, False),
        mdc=get_key(raw, prefix, "mdc", bool, False),
        mdc_interval=mdc_interval,
        dprnt=dprnt,
    )


def connector(config: HaasSerialMachine, hooks: ConnectorHooks) -> Connector:
    """XModem (or text) on the port; printed lines to ``hooks.on_dprnt``."""
    from opendnc.server.machines.haas_serial import HaasSerialConnector

    return HaasSerialConnector(config, on_dprnt=hooks.on_dprnt)


def capabilities(config: HaasSerialMachine) -> Capabilities:
    """A serial Haas punches programs to the listening port; drip-feed when opted in."""
    return Capabilities(
        dripfeed=config.dripfeed,
        dprnt=bool(config.dprnt),
        receive=True,
        status_fields=MDC_STATUS_FIELDS if config.mdc else frozenset(),
    )


SPEC = KindSpec(
    kind=MachineKind.HAAS_SERIAL,
    schema=HaasSerialMachine,
    keys=schema_keys(HaasSerialMachine),
    parse=parse,
    connector=connector,
    capabilities=capabilities,
    misplaced={
        "dripfeed": "drip-feed is for serial machines (haas_serial, serial)",
        "mdc": "only for haas_serial (a Haas NGC always reports by MDC over TCP)",
    },
)
