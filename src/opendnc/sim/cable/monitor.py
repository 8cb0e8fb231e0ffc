"""The cable's line monitor: a timestamped record of every byte that crosses the cable.

A serial sniffer for the virtual cable, in the spirit of the dumps of
docs/captures/haas-xmodem-opendnc.txt (Figures 23
and 24): each line says when bytes left the line, in which direction, and which bytes (after
noise: what the far side is handed, or loses unheard when nobody has it open)::

    0.011873 a>b 01 01 fe 25 0a 4f 30 30 30 31 ...
    0.012071 b>a 06

The time is in seconds since the cable was created: when the pump delivered the bytes, which
is at or just after the last one's line deadline (by the pump's batching, up to a millisecond,
plus its wake-up). Bytes delivered together share one line. The file is flushed whenever the
line goes quiet and at least every 0.2 s while it is busy. :func:`read_monitor` parses such a
file back into :class:`MonitorRecord` values, for tests and for the benchmark's block timing.
"""

from __future__ import annotations

import contextlib
import os
from dataclasses import dataclass
from pathlib import Path
from typing import TextIO

from opendnc.errors import InputError

DIRECTIONS = ("a>b", "b>a")
FLUSH_EVERY = 0.2  # seconds between flushes while the line is busy: cheap for the pump


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
        self._path = path
        self._started = started
        self._flushed = started
        self.error: InputError | None = None  # why the monitor stopped writing, if it did

    def record(self, direction: str, now: float, data: bytes) -> None:
        """Log ``data`` leaving the line at ``now`` (the cable's monotonic clock)."""
        self._write(format_line(now - self._started, direction, data), now)

    def flush(self, now: float) -> None:
        """Push buffered lines to the file (the pump calls this when the line goes quiet)."""
        self._write("", now, force=True)

    def _write(self, text: str, now: float, *, force: bool = False) -> None:
        if self.error is not None or self._file.closed:
            return
        try:
            if text:
                self._file.write(text)
            if force or now - self._flushed >= FLUSH_EVERY:
                self._file.flush()
                self._flushed = now
        except (OSError, ValueError) as exc:
            # a full disk must not stop the cable: the line goes on, the monitor says why not
            self.error = InputError(f"line monitor {self._path} stopped: {exc}")

    def close(self) -> None:
        """Flush and close the file. Safe to call twice."""
        if not self._file.closed:
            with contextlib.suppress(OSError):
                self._file.close()


def format_line(seconds: float, direction: str, data: bytes) -> str:
    """One monitor line, newline included."""
    return f"{seconds:.6f} {direction} {data.hex(' ')}\n"


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
