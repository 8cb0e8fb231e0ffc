"""Capture a probing run: map DPRNT lines to grid points, check them, store each at once.

:class:`PointMatcher` is sans-IO: feed it captured lines, it returns what each line meant
(:class:`Recorded`, :class:`Missing`, :class:`Repeated`, :class:`OutOfOrder`,
:class:`Mismatch`, :class:`Ignored`, :class:`RunStarted`, :class:`RunEnded`). A point is
only ever stored under the number the control printed, and only when the X and Y the
control printed are that point's, so a lost line shows up as missing and is never shifted
onto its neighbour. :func:`capture` drives it from a live port through the DPRNT listener.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

from opendnc.errors import InputError
from opendnc.haas.dprnt import parse_line
from opendnc.haas.listen import CallbackSink, CapturedLine, DprntListener, JsonlSink, open_source
from opendnc.surface.grid import Grid, GridPoint
from opendnc.surface.points import PointRow, PointsWriter, read_points


@dataclass(frozen=True, slots=True)
class Recorded:
    """Point ``point`` stored with height ``z``."""

    point: GridPoint
    z: float


@dataclass(frozen=True, slots=True)
class Missing:
    """Points expected before ``before`` that never arrived (numbers, ascending)."""

    numbers: tuple[int, ...]
    before: int


@dataclass(frozen=True, slots=True)
class Repeated:
    """Point ``number`` printed again; ``same`` when the height agrees with the stored one."""

    number: int
    z: float
    stored: float
    same: bool


@dataclass(frozen=True, slots=True)
class OutOfOrder:
    """Point ``number`` arrived after a later point (stored; it was missing until now)."""

    number: int
    after: int


@dataclass(frozen=True, slots=True)
class Mismatch:
    """A point line whose number, X or Y does not fit the grid; nothing stored."""

    text: str
    reason: str


@dataclass(frozen=True, slots=True)
class Ignored:
    """A line that is not a point line (other DPRNT output, noise)."""

    text: str


@dataclass(frozen=True, slots=True)
class RunStarted:
    """``SURFACE START``: the program (re)started; the order check starts again at point 1."""

    text: str


@dataclass(frozen=True, slots=True)
class RunEnded:
    """``SURFACE END``: the program finished; ``missing`` lists points never captured."""

    missing: tuple[int, ...]


MatchEvent = Recorded | Missing | Repeated | OutOfOrder | Mismatch | Ignored | RunStarted | RunEnded


@dataclass
class PointMatcher:
    """Map captured lines onto ``grid`` (see the module docstring)."""

    grid: Grid
    values: dict[int, float] = field(default_factory=dict)
    expected: int = 1
    last: int = 0
    ended: bool = False

    @property
    def tolerance(self) -> float:
        """How far a printed X/Y may sit from the grid: 1.5 printed steps."""
        return 1.5 * self.grid.units.resolution

    @property
    def complete(self) -> bool:
        """Every grid point has a height."""
        return len(self.values) == self.grid.size

    def missing(self) -> tuple[int, ...]:
        """Numbers of the points not captured yet."""
        return tuple(n for n in range(1, self.grid.size + 1) if n not in self.values)

    def preload(self, number: int, z: float) -> None:
        """Take a point captured by an earlier run (``--resume``)."""
        self.grid.point(number)
        self.values.setdefault(number, z)

    def feed(self, text: str) -> list[MatchEvent]:
        """What ``text`` (one captured line) means; may return several events."""
        # a serial line may carry stray control bytes (an XModem NAK, noise): not part of it
        text = "".join(char for char in text if char.isprintable())
        words = text.split()
        upper = [w.upper() for w in words]
        if upper[:2] == ["SURFACE", "START"]:
            self.expected, self.last, self.ended = 1, 0, False
            return [RunStarted(text)]
        if upper[:2] == ["SURFACE", "END"]:
            self.ended = True
            events: list[MatchEvent] = []
            if self.expected <= self.grid.size:
                gap = tuple(
                    n for n in range(self.expected, self.grid.size + 1) if n not in self.values
                )
                if gap:
                    events.append(Missing(gap, self.grid.size + 1))
            return [*events, RunEnded(self.missing())]
        parsed = parse_line(text)
        number, x, y, z = (parsed.get(k) for k in "PXYZ")
        if number is None or x is None or y is None or z is None:
            return [Ignored(text)]
        if number != int(number) or not 1 <= number <= self.grid.size:
            return [Mismatch(text, f"point {number:g} is not on the {self.grid.label} grid")]
        point = self.grid.point(int(number))
        tol = self.tolerance
        if abs(x - point.x) > tol or abs(y - point.y) > tol:
            return [
                Mismatch(
                    text,
                    f"point {point.number} printed at X{x:g} Y{y:g}, "
                    f"the grid has it at X{point.x:g} Y{point.y:g}",
                )
            ]
        return self._place(point, z)

    def _place(self, point: GridPoint, z: float) -> list[MatchEvent]:
        number = point.number
        events: list[MatchEvent] = []
        if number in self.values and number < self.expected:
            stored = self.values[number]
            same = abs(stored - z) <= self.grid.units.resolution / 2
            return [Repeated(number, z, stored, same)]
        if number < self.expected:
            events.append(OutOfOrder(number, self.last))
        elif number > self.expected:
            gap = tuple(n for n in range(self.expected, number) if n not in self.values)
            if gap:
                events.append(Missing(gap, number))
        if number >= self.expected:
            self.expected, self.last = number + 1, number
        if number in self.values:  # captured by an earlier (resumed) run: keep the first
            return events
        self.values[number] = z
        events.append(Recorded(point, z))
        return events


@dataclass
class CaptureReport:
    """How a capture ended."""

    captured: int
    total: int
    missing: tuple[int, ...]
    repeated: list[int] = field(default_factory=list)
    out_of_order: list[int] = field(default_factory=list)
    mismatched: list[str] = field(default_factory=list)
    reason: str = ""

    @property
    def complete(self) -> bool:
        """Every point was captured."""
        return not self.missing


def _z_text(text: str) -> str:
    """The Z number exactly as printed (``-0.0012``), so the file keeps the control's digits."""
    parsed = parse_line(text)
    for f in parsed.fields:
        if f.label.upper() == "Z":
            tail = text.upper().rsplit("Z", 1)[-1].strip()
            return tail.split()[0] if tail else repr(f.value)
    return ""


class CaptureSession:
    """Feed captured lines; store recorded points in ``writer``; report through ``on_event``."""

    def __init__(
        self,
        grid: Grid,
        writer: PointsWriter,
        *,
        on_event: Callable[[MatchEvent], None] = lambda event: None,
        done: Callable[[], None] = lambda: None,
    ) -> None:
        self.matcher = PointMatcher(grid)
        self.writer = writer
        self.on_event = on_event
        self.done = done
        self.report = CaptureReport(0, grid.size, ())

    def feed(self, line: CapturedLine) -> None:
        """Handle one captured line."""
        for event in self.matcher.feed(line.text):
            if isinstance(event, Recorded):
                point = event.point
                self.writer.write(
                    PointRow(
                        point.number,
                        point.row,
                        point.col,
                        point.x,
                        point.y,
                        event.z,
                        _z_text(line.text),
                        line.timestamp.isoformat(),
                        line.text,
                    )
                )
                self.report.captured += 1
            elif isinstance(event, Repeated):
                self.report.repeated.append(event.number)
            elif isinstance(event, OutOfOrder):
                self.report.out_of_order.append(event.number)
            elif isinstance(event, Mismatch):
                self.report.mismatched.append(event.reason)
            self.on_event(event)
            if self.matcher.complete:
                self.report.reason = "grid complete"
                self.done()
            elif isinstance(event, RunEnded):
                self.report.reason = "program ended with points missing"
                self.done()


def capture(
    source: str,
    grid: Grid,
    output: Path,
    *,
    baudrate: int = 9600,
    resume: bool = False,
    jsonl: Path | None = None,
    idle_timeout: float | None = None,
    on_event: Callable[[MatchEvent], None] = lambda event: None,
    on_status: Callable[[str], None] = lambda message: None,
    stop: threading.Event | None = None,
) -> CaptureReport:
    """Capture points from ``source`` (serial port, pyserial URL or ``tcp://HOST:PORT``)
    into ``output`` until the grid is complete, the program ends, ``idle_timeout`` seconds
    pass without a line, or ``stop`` is set."""
    preload: list[tuple[int, float]] = []
    if resume and output.exists() and output.stat().st_size > 0:
        previous = read_points(output)
        if previous.grid is not None and previous.grid != grid:
            raise InputError(
                f"{output} holds a {previous.grid.label} grid "
                f"({previous.grid.units.value}); --grid and units must match to resume"
            )
        preload = [(row.point, row.z) for row in previous.rows]
    writer = PointsWriter(output, grid, resume=resume)
    sinks: list[CallbackSink | JsonlSink] = []
    try:
        if jsonl is not None:
            sinks.append(JsonlSink(jsonl))
        listener = DprntListener(
            source,
            [],
            opener=lambda spec: open_source(spec, baudrate=baudrate),
            on_status=on_status,
        )
        session = CaptureSession(grid, writer, on_event=on_event, done=listener.stop)
        for number, z in preload:
            session.matcher.preload(number, z)
        if session.matcher.complete:
            session.report.reason = "grid already complete"
            return _finish(session)
        last_line = [datetime.now(UTC)]

        def got(line: CapturedLine) -> None:
            last_line[0] = datetime.now(UTC)
            session.feed(line)

        listener.sinks = [*sinks, CallbackSink(got)]
        watchdog = threading.Thread(
            target=_watch,
            args=(listener, last_line, idle_timeout, stop, session),
            daemon=True,
        )
        watchdog.start()
        listener.run()
        listener.stop()
        watchdog.join(2)
        return _finish(session)
    finally:
        writer.close()
        for sink in sinks:
            sink.close()


def _watch(
    listener: DprntListener,
    last_line: list[datetime],
    idle_timeout: float | None,
    stop: threading.Event | None,
    session: CaptureSession,
) -> None:
    while not listener.stop_event.wait(0.1):
        if stop is not None and stop.is_set():
            session.report.reason = session.report.reason or "stopped"
            listener.stop()
            return
        quiet = (datetime.now(UTC) - last_line[0]).total_seconds()
        if idle_timeout is not None and quiet > idle_timeout:
            session.report.reason = f"no line for {idle_timeout:g} s"
            listener.stop()
            return


def _finish(session: CaptureSession) -> CaptureReport:
    report = session.report
    report.missing = session.matcher.missing()
    report.captured = len(session.matcher.values)
    return report
