"""The IANA name of this computer's time zone: the shop's clock where none is configured
(``opendnc demo``), so the pages show the times of the people looking at them.

Python's own local time knows the zone's offset and abbreviation but not its name, which
``[server] timezone`` needs (for the clock changes to come); the name is where the system keeps
it: ``TZ``, the ``/etc/localtime`` link into the zone database, or ``/etc/timezone``.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Mapping
from pathlib import Path
from zoneinfo import ZoneInfo, ZoneInfoNotFoundError

__all__ = ["host_zone_name"]

_MARK = "zoneinfo/"


def host_zone_name(
    environ: Mapping[str, str] | None = None,
    localtime: Path = Path("/etc/localtime"),
    timezone_file: Path = Path("/etc/timezone"),
) -> str:
    """This computer's zone (``Europe/Berlin``), the first of ``TZ``, the ``localtime`` link
    and ``timezone_file`` that names a zone Python knows; ``UTC`` if none does (Windows
    keeps its zone elsewhere)."""
    env = os.environ if environ is None else environ
    candidates = [_from_path(env.get("TZ", "").removeprefix(":"))]
    with contextlib.suppress(OSError):  # no such link (Windows, a container without it)
        candidates.append(_from_path(str(localtime.resolve(strict=True))))
    with contextlib.suppress(OSError, UnicodeDecodeError):
        candidates.append(timezone_file.read_text(encoding="utf-8").strip())
    for name in candidates:
        if _known(name):
            return name
    return "UTC"


def _from_path(text: str) -> str:
    # /usr/share/zoneinfo/Europe/Berlin -> Europe/Berlin; a name stays as it is
    return text.rpartition(_MARK)[2] if _MARK in text else text


def _known(name: str) -> bool:
    if not name or name.startswith("/") or ".." in name:
        return False
    try:
        ZoneInfo(name)
    except (ZoneInfoNotFoundError, ValueError, OSError):
        return False
    return True
