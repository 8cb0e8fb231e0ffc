"""Operations logbook (``C_CC`` 27): text the control writes, announced later by ``M_CC``."""

from __future__ import annotations

import time
from collections.abc import Iterable
from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class LogRequest:
    """Parameter of ``C_CC`` 27: ``name;DD.MM.YYYY;hh:mm:ss;``."""

    name: str
    since: float  # epoch seconds


def parse_request(text: str) -> LogRequest:
    """Decode the parameter; ValueError on anything malformed."""
    parts = text.split(";")
    if len(parts) < 3 or not parts[0].strip():
        raise ValueError("expected name;DD.MM.YYYY;hh:mm:ss;")
    stamp = time.strptime(f"{parts[1].strip()} {parts[2].strip()}", "%d.%m.%Y %H:%M:%S")
    return LogRequest(parts[0].strip(), time.mktime(stamp))


def render(events: Iterable[tuple[float, str]], since: float, model: str) -> str:
    """The logbook: header line, then one dated line per event after ``since``."""
    lines = [
        "Operation Logbook Version 1.0",
        f"Control: {model}",
        f"Created: {time.strftime('%d.%m.%Y %H:%M:%S')}",
        "",
    ]
    for stamp, text in events:
        if stamp >= since:
            lines.append(f"{time.strftime('%d.%m.%Y %H:%M:%S', time.localtime(stamp))}  {text}")
    return "\r\n".join(lines) + "\r\n"
