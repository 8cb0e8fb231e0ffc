"""Haas NGC controls over Ethernet (MDC Q-commands, the net share, DPRNT over TCP): schema,
connector, what they can do."""

from __future__ import annotations

import re
from typing import Any

from opendnc.server.core.configkeys import ConfigError, get_key, port_range
from opendnc.server.kinds.base import (
    Capabilities,
    ConnectorHooks,
    DprntSource,
    KindSpec,
    schema_keys,
)
from opendnc.server.kinds.connector import Connector
from opendnc.server.kinds.haas_ngc.schema import HaasNgcMachine

__all__ = ["SPEC", "STATUS_FIELDS", "HaasNgcMachine", "tcp_dprnt"]

STATUS_FIELDS = frozenset({"execution", "mode", "native_mode", "program", "part_count", "tool"})


def tcp_dprnt(value: str, key: str) -> str:
    """``tcp://HOST:PORT`` (where a Haas prints, Setting 263), or ``""``."""
    if not value:
        return ""
    match = re.fullmatch(r"tcp://([^:/\s]+|\[[0-9A-Fa-f:]+\]):(\d{1,5})", value)
    if match is None or not 0 < int(match.group(2)) < 65536:
        raise ConfigError(key, f"expected tcp://HOST:PORT or serial, got {value!r}")
    return value


def parse(raw: dict[str, Any], prefix: str, common: dict[str, Any]) -> HaasNgcMachine:
    """A ``haas_ngc`` machine's own keys."""
    host = get_key(raw, prefix, "host", str, "")
    if not host:
        raise ConfigError(f"{prefix}.host", "a Haas NGC needs the control's address")
    mdc_port = get_key(raw, prefix, "mdc_port", int, 5051)
    port_range(mdc_port, f"{prefix}.mdc_port")
    dprnt = get_key(raw, prefix, "dprnt", str, "")
    if dprnt == "serial":
        raise ConfigError(f"{prefix}.dprnt", "serial is for a haas_serial machine (its own port)")
    return HaasNgcMachine(
        **common,
        host=host,
        mdc_port=mdc_port,
        share=get_key(raw, prefix, "share", str, ""),
        dprnt=tcp_dprnt(dprnt, f"{prefix}.dprnt"),
    )


def connector(config: HaasNgcMachine, hooks: ConnectorHooks) -> Connector:
    """MDC for status, the share for programs."""
    # imported here, not at the top: a server imports every kind but needs only the
    # connectors of the kinds it has machines of (docs/server.md#shape-components-and-kinds)
    from opendnc.server.kinds.haas_ngc.connector import HaasNgcConnector

    return HaasNgcConnector(config)


def capabilities(config: HaasNgcMachine) -> Capabilities:
    """Status by MDC; DPRNT when a source is configured."""
    return Capabilities(dprnt=bool(config.dprnt), status_fields=STATUS_FIELDS)


def dprnt(config: HaasNgcMachine) -> DprntSource | None:
    """The TCP port the control prints to (Setting 263), if configured."""
    return DprntSource(url=config.dprnt) if config.dprnt else None


def share(config: HaasNgcMachine) -> str:
    """The control's network share (the net share fills it and collects from it)."""
    return config.share


SPEC = KindSpec(
    kind="haas_ngc",
    label="Haas NGC · Ethernet",
    schema=HaasNgcMachine,
    keys=schema_keys(HaasNgcMachine),
    parse=parse,
    connector=connector,
    capabilities=capabilities,
    misplaced={
        "dprnt": "DPRNT is a Haas feature",
    },
    dprnt=dprnt,
    share=share,
)
