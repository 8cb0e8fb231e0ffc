"""DPRNT listener core: capture lines from a serial port or a TCP port, never lose one.

Every received line is timestamped, parsed (:func:`opendnc.haas.dprnt.parse_line`) and
written to each sink, which flushes per line. A line longer than
:data:`~opendnc.haas.dprnt.MAX_LINE` bytes is dropped whole, counted in
:attr:`ListenStats.dropped` and reported through ``on_status``; the lines around it are kept.

When the link breaks (or the listener is stopped) in the middle of a line, the text received
of it is kept, but marked: :attr:`CapturedLine.complete` is False, the CSV's ``complete``
column says ``no`` and the JSON record has ``"complete": false``. A cut line is what the
control printed up to the break, so it is kept for the record, but a consumer that only wants
whole lines filters on that column. The listener then reconnects with exponential backoff.
Clock and sleep are injected so tests run without waiting.
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
    TransportError,
    TransportTimeout,
)
from opendnc.haas.dprnt import (
    MAX_LINE,
    DprntLineFramer,
    DroppedLine,
    Field,
    FrameEvent,
    parse_line,
)
from opendnc.transport.base import ByteStream
from opendnc.transport.urls import open_stream


@dataclass(frozen=True, slots=True)
class CapturedLine:
    """One DPRNT line as received: when, raw text and the numbers found in it.

    ``complete`` is False for a line cut short by the end of the link (its line end never came).
    """

    timestamp: datetime
    text: str
    fields: tuple[Field, ...]
    complete: bool = True

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


CSV_HEADER = ("timestamp", "line", "fields", "complete")
"""Columns of :class:`CsvSink`; ``complete`` is ``yes``, or ``no`` for a line cut by the link."""


class CsvSink:
    """CSV with columns :data:`CSV_HEADER` (fields as ``X=1.5 Z=-2``), flushed per line.

    Appends to an existing file only when it has the same columns (:class:`InputError`
    otherwise), so one file never mixes two layouts.
    """

    def __init__(self, path: Path) -> None:
        path = Path(path)
        new = not path.exists() or path.stat().st_size == 0
        if not new:
            with path.open(encoding="utf-8", newline="") as existing:
                header = next(csv.reader(existing), [])
            if tuple(header) != CSV_HEADER:
                raise InputError(
                    f"{path} has columns {','.join(header)!r}, not {','.join(CSV_HEADER)!r}: "
                    "capture into a new file"
                )
        self._file: IO[str] = path.open("a", encoding="utf-8", newline="")
        self._writer = csv.writer(self._file)
        if new:
            self._writer.writerow(CSV_HEADER)
            self._file.flush()

    def write(self, line: CapturedLine) -> None:
        fields = " ".join(
            f"{f.label}={f.value:g}" if f.label else f"{f.value:g}" for f in line.fields
        )
        complete = "yes" if line.complete else "no"
        self._writer.writerow([line.timestamp.isoformat(), line.text, fields, complete])
        self._file.flush()

    def close(self) -> None:
        self._file.close()


class JsonlSink:
    """One JSON object per line: timestamp, line, numbers, fields, complete; flushed per line."""

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
            "complete": line.complete,
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
    """Counters a listener keeps.

    ``lines`` counts every line written to the sinks, ``cut`` those of them cut short by the
    end of a link, ``dropped`` the over-long lines dropped whole (never written).
    """

    lines: int = 0
    cut: int = 0
    dropped: int = 0
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

    def _handle(self, event: FrameEvent) -> None:
        if isinstance(event, DroppedLine):
            self.stats.dropped += 1
            cut = "" if event.complete else ", cut by the end of the link"
            self.on_status(
                f"dropped a line of {event.length} bytes{cut} (longer than {MAX_LINE}); "
                "lines before and after it are kept"
            )
            return
        parsed = parse_line(event.text)
        captured = CapturedLine(self.now(), event.text, parsed.fields, event.complete)
        for sink in self.sinks:
            sink.write(captured)
        self.stats.lines += 1
        if not event.complete:
            self.stats.cut += 1

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
                framer.feed(data)
                for event in framer.events():
                    self._handle(event)
                    if max_lines is not None and self.stats.lines >= max_lines:
                        return True
            self._end_of_stream(framer)  # stopped: keep, marked cut, a line whose end never came
            return True
        except (PeerClosed, TransportError):
            self._end_of_stream(framer)  # link gone: the same
            return max_lines is not None and self.stats.lines >= max_lines

    def _end_of_stream(self, framer: DprntLineFramer) -> None:
        tail = framer.end_of_stream()
        if tail is not None:
            self._handle(tail)
