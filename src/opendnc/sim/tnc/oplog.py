"""Operations logbook (``C_CC`` 27): text the control writes, announced later by ``M_CC``."""

from __future__ import annotations

import time
from collections.abc import Iterable
from dataclasses import dataclass

from opendnc.errors import ControlRefused
from opendnc.lsv2.constants import ErrorCode as E


@dataclass(frozen=True, slots=True)
class LogRequest:
    """Parameter of ``C_CC`` 27: ``name;DD.MM.YYYY;hh:mm:ss;``."""

    name: str
    since: float  # epoch seconds


def parse_request(text: str) -> LogRequest:
    """Decode the parameter; refused (``T_ER_BAD_PARAMETER``) when malformed."""
    parts = text.split(";")
    if len(parts) < 3 or not parts[0].strip():
        raise ControlRefused(E.T_ER_BAD_PARAMETER, "expected name;DD.MM.YYYY;hh:mm:ss;")
    try:
        stamp = time.strptime(f"{parts[1].strip()} {parts[2].strip()}", "%d.%m.%Y %H:%M:%S")
    except ValueError:
        raise ControlRefused(E.T_ER_BAD_PARAMETER, f"bad date {parts[1]};{parts[2]}") from None
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
