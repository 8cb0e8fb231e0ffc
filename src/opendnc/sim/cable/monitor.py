"""The cable's line monitor: a timestamped record of every byte that crosses the cable.

A serial sniffer for the virtual cable, in the spirit of the dumps in seed 003 (Figures 23
and 24): each line says when bytes left the line, in which direction, and which bytes (after
noise, as the receiving side sees them)::

    0.011873 a>b 01 01 fe 25 0a 4f 30 30 30 31 ...
    0.012071 b>a 06

The time is in seconds since the cable was created. Bytes that leave the line together (one
delivery of the pump) share one line. :func:`read_monitor` parses such a file back into
:class:`MonitorRecord` values, for tests and for the benchmark's block timing.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import TextIO

from opendnc.errors import InputError

DIRECTIONS = ("a>b", "b>a")
FLUSH_EVERY = 0.2  # seconds between flushes: live enough for `tail -f`, cheap for the pump


@dataclass(frozen=True, slots=True)
class MonitorRecord:
    """Bytes that left the line together: ``seconds`` after the start, ``direction`` a>b/b>a."""

    seconds: float
    direction: str
    data: bytes


class LineMonitor:
    """Writes monitor lines to ``path`` (created or truncated); the cable's pump calls it."""

    def __init__(self, path: str | os.PathLike[str], started: float) -> None:
        try:
            self._file: TextIO = open(path, "w", encoding="ascii")  # noqa: SIM115 - closed by close()
        except OSError as exc:
            raise InputError(f"cannot write the line monitor to {path}: {exc}") from exc
        self._started = started
        self._flushed = started

    def record(self, direction: str, now: float, data: bytes) -> None:
        """Log ``data`` leaving the line at ``now`` (the cable's monotonic clock)."""
        if self._file.closed:
            return  # a pump that outlived close() must not die on the closed file
        self._file.write(f"{now - self._started:.6f} {direction} {data.hex(' ')}\n")
        if now - self._flushed >= FLUSH_EVERY:
            self._file.flush()
            self._flushed = now

    def close(self) -> None:
        """Flush and close the file. Safe to call twice."""
        if not self._file.closed:
            self._file.close()


def _parse_line(number: int, line: str) -> MonitorRecord:
    parts = line.split(" ", 2)
    if len(parts) != 3:
        raise InputError(f"line monitor, line {number}: expected 'SECONDS DIRECTION HEX'")
    seconds_text, direction, hex_text = parts
    try:
        seconds = float(seconds_text)
    except ValueError:
        raise InputError(f"line monitor, line {number}: bad time {seconds_text!r}") from None
    if not seconds >= 0 or seconds == float("inf"):  # also rejects NaN
        raise InputError(f"line monitor, line {number}: bad time {seconds_text!r}")
    if direction not in DIRECTIONS:
        raise InputError(f"line monitor, line {number}: bad direction {direction!r}")
    try:
        data = bytes.fromhex(hex_text)
    except ValueError:
        raise InputError(f"line monitor, line {number}: bad hex bytes") from None
    if not data:
        raise InputError(f"line monitor, line {number}: no bytes")
    return MonitorRecord(seconds, direction, data)


def parse_monitor(text: str) -> list[MonitorRecord]:
    """Parse monitor lines; :class:`~opendnc.errors.InputError` names the first bad line."""
    return [
        _parse_line(number, line)
        for number, line in enumerate(text.splitlines(), start=1)
        if line.strip()
    ]


def read_monitor(path: str | os.PathLike[str]) -> list[MonitorRecord]:
    """Read a monitor file written by the cable (``--monitor``)."""
    try:
        text = Path(path).read_text(encoding="ascii")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read the line monitor {path}: {exc}") from exc
    return parse_monitor(text)
