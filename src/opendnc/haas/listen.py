"""DPRNT listener core: capture lines from a serial port or a TCP port, never lose one.

Every received line is timestamped, parsed (:func:`opendnc.haas.dprnt.parse_line`) and
written to each sink, which flushes per line. When the link breaks, the unterminated tail is
kept as a line, and the listener reconnects with exponential backoff. Clock and sleep are
injected so tests run without waiting.
"""

from __future__ import annotations

import csv
import json
import threading
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import IO, Protocol

from opendnc.errors import (
    InputError,
    PeerClosed,
    RemoteProtocolError,
    TransportError,
    TransportTimeout,
)
from opendnc.haas.dprnt import DprntLineFramer, Field, parse_line
from opendnc.transport.base import ByteStream
from opendnc.transport.urls import open_stream


@dataclass(frozen=True, slots=True)
class CapturedLine:
    """One DPRNT line as received: when, raw text and the numbers found in it."""

    timestamp: datetime
    text: str
    fields: tuple[Field, ...]

    @property
    def numbers(self) -> tuple[float, ...]:
        """Every number in the line, in order."""
        return tuple(f.value for f in self.fields)


def open_source(spec: str, *, baudrate: int = 9600, timeout: float = 0.5) -> ByteStream:
    """Open ``tcp://HOST:PORT`` or ``socket://HOST:PORT`` as TCP, anything else as a pyserial
    URL or device (:func:`~opendnc.transport.urls.open_stream`); a malformed address is an
    :class:`InputError`, not something to retry."""
    return open_stream(spec, baudrate, timeout=timeout)


class LineSink(Protocol):
    """Receives every captured line."""

    def write(self, line: CapturedLine) -> None:
        """Store ``line`` durably (flush before returning)."""
        ...

    def close(self) -> None:
        """Release the sink."""
        ...


class CsvSink:
    """CSV with columns ``timestamp, line, fields`` (``X=1.5 Z=-2``), flushed per line."""

    def __init__(self, path: Path) -> None:
        new = not Path(path).exists() or Path(path).stat().st_size == 0
        self._file: IO[str] = Path(path).open("a", encoding="utf-8", newline="")  # noqa: SIM115
        self._writer = csv.writer(self._file)
        if new:
            self._writer.writerow(["timestamp", "line", "fields"])
            self._file.flush()

    def write(self, line: CapturedLine) -> None:
        fields = " ".join(
            f"{f.label}={f.value:g}" if f.label else f"{f.value:g}" for f in line.fields
        )
        self._writer.writerow([line.timestamp.isoformat(), line.text, fields])
        self._file.flush()

    def close(self) -> None:
        self._file.close()


class JsonlSink:
    """One JSON object per line: timestamp, line, numbers, fields; flushed per line."""

    def __init__(self, path: Path | None = None, stream: IO[str] | None = None) -> None:
        self._own = stream is None
        if stream is None and path is None:
            raise InputError("JsonlSink needs a path or a stream")
        self._file: IO[str] = stream or Path(str(path)).open("a", encoding="utf-8")  # noqa: SIM115

    def write(self, line: CapturedLine) -> None:
        record = {
            "timestamp": line.timestamp.isoformat(),
            "line": line.text,
            "numbers": list(line.numbers),
            "fields": [{"label": f.label, "value": f.value} for f in line.fields],
        }
        self._file.write(json.dumps(record) + "\n")
        self._file.flush()

    def close(self) -> None:
        if self._own:
            self._file.close()


class CallbackSink:
    """Hand each line to a function (console output, tests)."""

    def __init__(self, func: Callable[[CapturedLine], None]) -> None:
        self._func = func

    def write(self, line: CapturedLine) -> None:
        self._func(line)

    def close(self) -> None:
        """Nothing to release."""


def _now() -> datetime:
    return datetime.now(UTC)


@dataclass
class ListenStats:
    """Counters a listener keeps."""

    lines: int = 0
    connects: int = 0
    disconnects: int = 0
    errors: int = 0


class DprntListener:
    """Capture DPRNT lines from ``source`` into ``sinks`` until stopped.

    ``opener`` opens the link (default :func:`open_source`); ``now`` and ``sleep`` are the
    injected clock. ``on_status`` receives human-readable connect/disconnect messages.
    A link that drops is reopened with backoff; with ``retry_unopened=False`` a port that
    does not open the first time raises its :class:`TransportError` instead.
    """

    def __init__(
        self,
        source: str,
        sinks: list[LineSink],
        *,
        opener: Callable[[str], ByteStream] = open_source,
        now: Callable[[], datetime] = _now,
        sleep: Callable[[float], object] | None = None,
        backoff_start: float = 0.5,
        backoff_max: float = 10.0,
        on_status: Callable[[str], None] = lambda message: None,
        retry_unopened: bool = True,
    ) -> None:
        self.source = source
        self.sinks = sinks
        self.opener = opener
        self.now = now
        self.stats = ListenStats()
        self.stop_event = threading.Event()
        # waiting on the stop event lets stop() cut a reconnect backoff short
        self.sleep = sleep or self.stop_event.wait
        self.backoff_start, self.backoff_max = backoff_start, backoff_max
        self.on_status = on_status
        self.retry_unopened = retry_unopened

    def stop(self) -> None:
        """Ask :meth:`run` to return (from another thread or a sink)."""
        self.stop_event.set()

    def _emit(self, text: str) -> None:
        parsed = parse_line(text)
        captured = CapturedLine(self.now(), text, parsed.fields)
        for sink in self.sinks:
            sink.write(captured)
        self.stats.lines += 1

    def run(self, max_lines: int | None = None, max_connects: int | None = None) -> ListenStats:
        """Listen until :meth:`stop`, ``max_lines`` lines, or ``max_connects`` links ended."""
        delay = self.backoff_start
        while not self.stop_event.is_set():
            if max_connects is not None and self.stats.connects >= max_connects:
                break
            try:
                stream = self.opener(self.source)
            except TransportError as exc:
                self.stats.errors += 1
                if not self.retry_unopened and self.stats.connects == 0:
                    raise  # never opened: a wrong port, not a dropped link
                self.on_status(f"cannot open {self.source}: {exc}; retrying in {delay:g} s")
                self.sleep(delay)
                delay = min(delay * 2, self.backoff_max)
                continue
            self.stats.connects += 1
            self.on_status(f"listening on {self.source}")
            delay = self.backoff_start
            try:
                if self._pump(stream, max_lines):
                    break
            finally:
                stream.close()
            self.stats.disconnects += 1
            self.on_status(f"{self.source} disconnected; reconnecting in {delay:g} s")
            if not self.stop_event.is_set():
                self.sleep(delay)
                delay = min(delay * 2, self.backoff_max)
        return self.stats

    def _pump(self, stream: ByteStream, max_lines: int | None) -> bool:
        """Read until the link breaks (False) or the listener is done (True)."""
        framer = DprntLineFramer()
        try:
            while not self.stop_event.is_set():
                try:
                    data = stream.read(4096)
                except TransportTimeout:
                    continue
                try:
                    framer.feed(data)
                except RemoteProtocolError as exc:
                    self.stats.errors += 1
                    self.on_status(f"dropped garbage: {exc}")
                for line in framer.lines():
                    self._emit(line)
                    if max_lines is not None and self.stats.lines >= max_lines:
                        return True
            self._emit_tail(framer)  # stopped: keep a line whose end never came
            return True
        except (PeerClosed, TransportError):
            self._emit_tail(framer)  # link gone: keep a line whose end never came
            return max_lines is not None and self.stats.lines >= max_lines

    def _emit_tail(self, framer: DprntLineFramer) -> None:
        tail = framer.flush()
        if tail is not None:
            self._emit(tail)
