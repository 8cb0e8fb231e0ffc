"""Heidenhain controls over LSV2 (TCP, or RS-232 with ``serial``): schema, connector, what they
can do, the out-tray folder collected into the inbox and the folder the file browser opens."""

from __future__ import annotations

from typing import Any

from opendnc.errors import InputError
from opendnc.server.core.configkeys import ConfigError, get_key, port_range, table_at
from opendnc.server.kinds.base import (
    Capabilities,
    ConnectorHooks,
    KindSpec,
    ReceiveFolder,
    parse_profile,
    schema_keys,
)
from opendnc.server.kinds.connector import Connector
from opendnc.server.kinds.files import check_path
from opendnc.server.kinds.lsv2.schema import LSV2_SERIAL, Lsv2Machine

__all__ = ["LSV2_SERIAL", "SPEC", "STATUS_FIELDS", "Lsv2Machine"]

STATUS_FIELDS = frozenset({"execution", "mode", "program", "line", "tool", "overrides", "errors"})


def parse(raw: dict[str, Any], prefix: str, common: dict[str, Any]) -> Lsv2Machine:
    """An ``lsv2`` machine's own keys."""
    host = get_key(raw, prefix, "host", str, "")
    serial = get_key(raw, prefix, "serial", str, "")
    if not host and not serial:
        raise ConfigError(f"{prefix}.host", "an LSV2 machine needs host (TCP) or serial")
    port = get_key(raw, prefix, "port", int, 19000)
    port_range(port, f"{prefix}.port")
    receive = _receive(raw, prefix)
    return Lsv2Machine(
        **common,
        host=host,
        port=port,
        serial=serial,
        profile=parse_profile(
            table_at(raw, "serial_profile"), f"{prefix}.serial_profile", LSV2_SERIAL, line_only=True
        ),
        folder=get_key(raw, prefix, "folder", str, ""),
        receive_folder=receive[0],
        receive_pattern=receive[1],
        receive_every=receive[2],
        after_receive=receive[3],
    )


def _receive(raw: dict[str, Any], prefix: str) -> tuple[str, str, int, str]:
    """The auto-receive folder: (folder, pattern, every, after)."""
    folder = get_key(raw, prefix, "receive_folder", str, "")
    pattern = get_key(raw, prefix, "receive_pattern", str, "*")
    every = get_key(raw, prefix, "receive_every", int, 5)
    after = get_key(raw, prefix, "after_receive", str, "keep")
    if not folder:
        for key in ("receive_pattern", "receive_every", "after_receive"):
            if key in raw:
                raise ConfigError(f"{prefix}.{key}", "needs receive_folder")
        return "", pattern, every, after
    try:
        folder = check_path(folder)
    except InputError as exc:
        raise ConfigError(f"{prefix}.receive_folder", str(exc)) from None
    if not pattern or len(pattern) > 100 or any(c in pattern for c in "/\\:"):
        raise ConfigError(f"{prefix}.receive_pattern", "expected a file name glob like *.h")
    if not 1 <= every <= 10_000:
        raise ConfigError(f"{prefix}.receive_every", "expected 1..10000 polls")
    if after not in ("keep", "delete"):
        raise ConfigError(f"{prefix}.after_receive", "expected keep or delete")
    return folder, pattern, every, after


def connector(config: Lsv2Machine, hooks: ConnectorHooks) -> Connector:
    """One LSV2 session (TCP or RS-232)."""
    # imported here, not at the top: a server imports every kind but needs only the
    # connectors of the kinds it has machines of (docs/server.md#shape-components-and-kinds)
    from opendnc.server.kinds.lsv2.connector import Lsv2Connector

    return Lsv2Connector(config)


def capabilities(config: Lsv2Machine) -> Capabilities:
    """A file browser over the machine's own session (TCP or RS-232 alike); receiving when
    an out-tray folder is configured."""
    return Capabilities(
        file_browser=True, receive=bool(config.receive_folder), status_fields=STATUS_FIELDS
    )


def receive_folder(config: Lsv2Machine) -> ReceiveFolder | None:
    """The out-tray folder, if configured."""
    if not config.receive_folder:
        return None
    return ReceiveFolder(
        config.receive_folder, config.receive_pattern, config.receive_every, config.after_receive
    )


def program_folder(config: Lsv2Machine) -> str:
    """Where programs go on the control (TNC:/nc_prog unless ``folder`` says otherwise)."""
    return check_path(config.folder or "TNC:/nc_prog")


SPEC = KindSpec(
    kind="lsv2",
    label="Heidenhain · LSV2",
    schema=Lsv2Machine,
    keys=schema_keys(Lsv2Machine),
    parse=parse,
    connector=connector,
    capabilities=capabilities,
    misplaced={
        "receive_folder": "only for lsv2 (a serial Haas punches by itself, "
        "a Haas NGC's share is collected)",
    },
    receive_folder=receive_folder,
    program_folder=program_folder,
)
