"""The ``[clients]`` settings: how long a client may take to read, and how many event streams
it may hold (docs/server.md#bounded-clients). The limits themselves are kept by
:mod:`opendnc.server.http.clients`; this is the part the configuration parser reads."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from opendnc.server.core.configkeys import ConfigError, get_key, known_keys

__all__ = ["ClientLimits", "parse_clients"]


@dataclass(frozen=True)
class ClientLimits:
    """The ``[clients]`` settings (seconds, counts)."""

    send_timeout: float = 30.0  # a piece of a response not taken by the client in this: cut
    heartbeat: float = 5.0  # an event stream's comment when it has nothing else to send
    stream_idle: float = 900.0  # an event stream with only heartbeats for this long ends
    # event streams one user (or a key's user) may hold open: a shop floor's tablets often
    # share one account, two streams a page
    streams_per_user: int = 200
    streams_total: int = 2000  # event streams the server holds open


# [clients] keys: (smallest, largest) each may be
_RANGES: dict[str, tuple[float, float]] = {
    "send_timeout": (1.0, 3600.0),
    "heartbeat": (1.0, 300.0),
    "stream_idle": (1.0, 86400.0),
    "streams_per_user": (1, 100_000),
    "streams_total": (1, 100_000),
}


def parse_clients(table: dict[str, Any]) -> ClientLimits:
    """The ``[clients]`` table; :class:`~opendnc.server.core.configkeys.ConfigError` names a
    bad key."""
    known_keys(table, "clients", set(_RANGES))
    default = ClientLimits()
    values: dict[str, Any] = {}
    for key, (low, high) in _RANGES.items():
        kind = int if isinstance(low, int) else float
        value = get_key(table, "clients", key, kind, getattr(default, key))
        if not low <= value <= high:
            raise ConfigError(f"clients.{key}", f"expected {low:g} to {high:g}, got {value!r}")
        values[key] = value
    return ClientLimits(**values)
