"""The small vocabulary every part of the configuration parser shares: the error that names a
key, and typed reads of one key of a TOML table (docs/server.md#shape-components-and-kinds).

Kept apart from :mod:`opendnc.server.config.shop` so each machine kind's module
(:mod:`opendnc.server.kinds`) parses its own keys with the same words and messages.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from opendnc.errors import InputError

__all__ = ["NAME", "ConfigError", "get_key", "known_keys", "port_range", "table_at"]

# Machine names appear in URLs, file names and MQTT topics: keep them to a safe alphabet.
NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$")


class ConfigError(InputError):
    """The configuration file is malformed; the message names the key."""

    def __init__(self, key: str, problem: str, *, source: Path | None = None) -> None:
        self.key = key
        self.problem = problem
        self.source = source  # the file, once known: the message then starts with its name
        text = f"{key}: {problem}" if key else problem
        super().__init__(f"{source}: {text}" if source is not None else text)


def table_at(raw: dict[str, Any], key: str) -> dict[str, Any]:
    """The sub-table ``key`` of ``raw`` (empty when absent)."""
    value = raw.get(key, {})
    if not isinstance(value, dict):
        raise ConfigError(key, "expected a table")
    return value


def known_keys(table: dict[str, Any], prefix: str, keys: set[str]) -> None:
    """Refuse a key not in ``keys`` (a misspelt key silently ignored is the worst kind of
    configuration error)."""
    for key in table:
        if key not in keys:
            name = f"{prefix}.{key}" if prefix else key
            raise ConfigError(name, f"unknown key (expected one of {', '.join(sorted(keys))})")


def get_key(table: dict[str, Any], prefix: str, key: str, kind: type, default: Any) -> Any:
    """``table[key]`` checked to be a ``kind`` (``default`` when absent)."""
    value = table.get(key, default)
    # bool is an int in Python; a TOML `port = true` must not pass as port 1.
    if kind in (int, float) and isinstance(value, bool):
        raise ConfigError(f"{prefix}.{key}", f"expected a number, got {value!r}")
    if kind is float and isinstance(value, int):
        value = float(value)
    if not isinstance(value, kind):
        raise ConfigError(f"{prefix}.{key}", f"expected {kind.__name__}, got {value!r}")
    return value


def port_range(port: int, key: str) -> None:
    """Refuse a TCP port outside 1..65535."""
    if not 0 < port < 65536:
        raise ConfigError(key, f"expected a TCP port 1..65535, got {port}")
