"""Tape-code controls on RS-232 (Fanuc, Mitsubishi, Mazak, Okuma, Siemens, Fagor): schema,
connector, what they can do (docs/server.md#tape-code-controls-serial).

A machine names a profile of the tape engine (:mod:`opendnc.tape.profiles`) and may change a
few of its settings; the profile, as changed, is resolved once when the configuration is read,
so a bad combination (an EIA code on a 7E line) is a one-line configuration error at start, not
a failure at the first job.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

from opendnc.errors import InputError
from opendnc.nccheck.limits import Envelope
from opendnc.server.core.configkeys import ConfigError, get_key
from opendnc.server.kinds.base import (
    Capabilities,
    ConnectorHooks,
    KindSpec,
)
from opendnc.server.kinds.connector import Connector
from opendnc.server.kinds.serial.schema import SerialMachine
from opendnc.tape.codes import Code, Eob
from opendnc.tape.profiles import PROFILES, Profile, get_profile

__all__ = ["CONTROL_OF_PROFILE", "SPEC", "STATUS_FIELDS", "SerialMachine"]

STATUS_FIELDS = frozenset({"execution", "program", "line"})
"""What the status holds: the control reports nothing, so these are what the server drives
(a drip-feed is the program running, at the line fed)."""

CONTROL_OF_PROFILE = {
    "fanuc-0i": "fanuc-mill",
    "fanuc-30i": "fanuc-mill",
    "haas": "haas-mill",
}
"""The G-code dialect a program check uses for a profile (docs/check.md), unless the machine's
``control`` key names another (``fanuc-lathe``); profiles not listed are checked with the
guessed Haas/Fanuc union, which reports no code either control knows."""

_BAUDS = (300, 600, 1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200)
_EOBS = {e.value: e for e in Eob}
_CODES = {c.value: c for c in Code}
_KEYS = frozenset(
    {
        "serial", "profile", "baud", "code", "eob", "tv_check", "wait_dc1", "punch_dc2",
        "dripfeed", "verify", "verify_timeout",
    }
)  # fmt: skip


def parse(raw: dict[str, Any], prefix: str, common: dict[str, Any]) -> SerialMachine:
    """A ``serial`` machine's own keys."""
    serial = get_key(raw, prefix, "serial", str, "")
    if not serial:
        raise ConfigError(f"{prefix}.serial", "a serial machine needs a device or URL")
    name = get_key(raw, prefix, "profile", str, "fanuc-0i")
    try:
        base = get_profile(name)
    except InputError:
        raise ConfigError(f"{prefix}.profile", f"expected one of {', '.join(PROFILES)}") from None
    changes: dict[str, Any] = {}
    if "baud" in raw:
        baud = get_key(raw, prefix, "baud", int, base.baud)
        if baud not in _BAUDS:
            raise ConfigError(f"{prefix}.baud", f"{baud} is not a standard rate")
        changes["baud"] = baud
    if "code" in raw:
        changes["code"] = _choice(raw, prefix, "code", _CODES)
    if "eob" in raw:
        changes["eob"] = _choice(raw, prefix, "eob", _EOBS)
    for key in ("tv_check", "wait_dc1", "punch_dc2"):
        if key in raw:
            changes[key] = get_key(raw, prefix, key, bool, getattr(base, key))
    if changes.get("code") is Code.EIA and "line" not in changes:
        # EIA carries its own parity in channel 5: the line is 8 bits without UART parity
        changes["line"] = "8N" + base.line[2:]
    try:
        tape = base.with_changes(**changes)
    except InputError as exc:
        raise ConfigError(f"{prefix}.profile", str(exc)) from None
    verify = get_key(raw, prefix, "verify", str, "")
    if verify not in ("", "punch"):
        raise ConfigError(f"{prefix}.verify", 'expected "punch" (or leave it out)')
    verify_timeout = get_key(raw, prefix, "verify_timeout", float, 120.0)
    if not 1 <= verify_timeout <= 3600:
        raise ConfigError(f"{prefix}.verify_timeout", "expected seconds between 1 and 3600")
    return SerialMachine(
        **{**common, "envelope": _with_control(common.get("envelope"), tape)},
        serial=serial,
        tape=tape,
        dripfeed=get_key(raw, prefix, "dripfeed", bool, False),
        verify=verify,
        verify_timeout=verify_timeout,
    )


def _choice(raw: dict[str, Any], prefix: str, key: str, choices: dict[str, Any]) -> Any:
    text = get_key(raw, prefix, key, str, "").lower()
    if text not in choices:
        raise ConfigError(f"{prefix}.{key}", f"expected one of {', '.join(choices)}")
    return choices[text]


def _with_control(envelope: Envelope | None, tape: Profile) -> Envelope | None:
    """The machine's envelope with the profile's G-code dialect, unless ``control`` named one."""
    control = CONTROL_OF_PROFILE.get(tape.name)
    if control is None or (envelope is not None and envelope.control is not None):
        return envelope
    if envelope is None:
        return Envelope(control=control)
    return replace(envelope, control=control)


def connector(config: SerialMachine, hooks: ConnectorHooks) -> Connector:
    """The tape engine on the port; what it does goes to ``hooks.on_status``."""
    # imported here, not at the top: a server imports every kind but needs only the
    # connectors of the kinds it has machines of (docs/server.md#shape-components-and-kinds)
    from opendnc.server.kinds.serial.connector import TapeConnector

    return TapeConnector(config, on_status=hooks.on_status)


def capabilities(config: SerialMachine) -> Capabilities:
    """A tape control punches programs to the listening port; drip-feed when opted in."""
    return Capabilities(
        dripfeed=config.dripfeed,
        receive=True,
        status_fields=STATUS_FIELDS,
        # a report program's O-number as the profile takes it (a Fanuc 0i: O9998)
        o_digits=min(5, config.tape.o_digits),
    )


SPEC = KindSpec(
    kind="serial",
    label="Tape code · RS-232",
    schema=SerialMachine,
    keys=_KEYS,
    parse=parse,
    connector=connector,
    capabilities=capabilities,
)
