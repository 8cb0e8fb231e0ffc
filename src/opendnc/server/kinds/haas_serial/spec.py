"""Haas controls on RS-232 (XModem or plain text, drip-feed, MDC and DPRNT on the same port):
schema, connector, what they can do."""

from __future__ import annotations

from typing import Any

from opendnc.server.core.configkeys import ConfigError, get_key, table_at
from opendnc.server.kinds.base import (
    Capabilities,
    ConnectorHooks,
    DprntSource,
    KindSpec,
    SerialProfile,
    parse_profile,
    schema_keys,
)
from opendnc.server.kinds.connector import Connector
from opendnc.server.kinds.haas_ngc.spec import tcp_dprnt
from opendnc.server.kinds.haas_serial.schema import HaasSerialMachine

__all__ = ["MDC_STATUS_FIELDS", "SPEC", "HaasSerialMachine"]

MDC_STATUS_FIELDS = frozenset({"execution", "mode", "native_mode", "program", "part_count"})


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
    # imported here, not at the top: a server imports every kind but needs only the
    # connectors of the kinds it has machines of (docs/server.md#shape-components-and-kinds)
    from opendnc.server.kinds.haas_serial.connector import HaasSerialConnector

    return HaasSerialConnector(config, on_dprnt=hooks.on_dprnt)


def capabilities(config: HaasSerialMachine) -> Capabilities:
    """A serial Haas punches programs to the listening port; drip-feed when opted in."""
    return Capabilities(
        dripfeed=config.dripfeed,
        dprnt=bool(config.dprnt),
        receive=True,
        status_fields=MDC_STATUS_FIELDS if config.mdc else frozenset(),
    )


def dprnt(config: HaasSerialMachine) -> DprntSource | None:
    """The machine's own port (the connector taps it) or a TCP port, if configured."""
    if config.dprnt == "serial":
        return DprntSource(own_port=config.serial)
    return DprntSource(url=config.dprnt) if config.dprnt else None


SPEC = KindSpec(
    kind="haas_serial",
    label="Haas · RS-232",
    schema=HaasSerialMachine,
    keys=schema_keys(HaasSerialMachine),
    parse=parse,
    connector=connector,
    capabilities=capabilities,
    misplaced={
        "dripfeed": "drip-feed is for serial machines (haas_serial, serial)",
        "mdc": "only for haas_serial (a Haas NGC always reports by MDC over TCP)",
    },
    dprnt=dprnt,
)
