"""The whole round trip against a Haas: generate, load, wait for (or start) the run, capture.

Two ways to reach the control:

* **serial** (``--haas`` is a port or pyserial URL): the program goes over XModem (Setting
  14 = XMODEM, the operator puts the control in receive) and the DPRNT lines come back on
  the same port. With ``--unsafe`` the program is drip-fed (DNC) instead, which starts it on
  the machine, and the DPRNT lines are read from the same stream while it feeds.
* **Ethernet** (``--haas`` is a host name with ``--share``): the program is copied to the
  control's Net Share, DPRNT is read from ``tcp://HOST:PORT`` (Setting 261 = TCP, 263 = port).
  No Haas command starts a program over Ethernet, so the operator always presses cycle start.

Without ``--unsafe`` nothing moves the machine from here: the program is loaded and opendnc
waits for the operator's cycle start, as shops work.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

from opendnc.errors import InputError, PeerClosed, TransportTimeout
from opendnc.haas.dprnt import DprntLineFramer, FramedLine, parse_line
from opendnc.haas.listen import CapturedLine
from opendnc.surface.capture import CaptureReport, CaptureSession, MatchEvent, capture
from opendnc.surface.points import PointsWriter
from opendnc.surface.program import SurfaceProgram
from opendnc.transport.base import PortStream


def is_serial(spec: str) -> bool:
    """A device path, COM port or pyserial URL (``socket://`` counts: a serial server)."""
    lowered = spec.lower()
    return (
        spec.startswith("/")
        or lowered.startswith("com")
        or ("://" in spec and not lowered.startswith("tcp://"))
    )


@dataclass
class MeasurePlan:
    """Where the program goes and where the points come from."""

    haas: str
    program: SurfaceProgram
    program_path: Path
    points: Path
    baud: int = 9600
    share: str | None = None
    dprnt_port: int = 5052
    unsafe: bool = False
    idle_timeout: float | None = None
    resume: bool = False


def load_program(plan: MeasurePlan, say: Callable[[str], None]) -> None:
    """Copy the program to the control (XModem or Net Share); never starts it."""
    plan.program_path.write_text(plan.program.text, encoding="ascii")
    if plan.share is not None:
        from opendnc.haas import share

        target = share.parse_target(plan.share)
        share.push([plan.program_path], target)
        say(f"{plan.program.name} copied to {target.describe(plan.program_path.name)}")
        return
    if not is_serial(plan.haas):
        raise InputError(
            f"--haas {plan.haas!r} is not a serial port: over Ethernet give --share "
            "(Net Share folder or smb://...) to load the program"
        )
    from opendnc.xmodem.files import send_file
    from opendnc.xmodem.framing import Mode

    say(f"sending {plan.program.name} by XModem on {plan.haas}: put the control in receive")
    report = send_file(plan.haas, plan.program_path, mode=Mode.CHECKSUM, baud=plan.baud)
    say(f"{plan.program.name} loaded ({report.size} bytes)")


def measure(
    plan: MeasurePlan,
    *,
    say: Callable[[str], None],
    on_event: Callable[[MatchEvent], None] = lambda event: None,
    stop: threading.Event | None = None,
) -> CaptureReport:
    """Load (or drip-feed, with ``unsafe``), then capture every point into ``plan.points``."""
    grid = plan.program.grid
    if plan.unsafe:
        if not is_serial(plan.haas) or plan.share is not None:
            raise InputError(
                "--unsafe starts the program by drip-feeding it over serial; over Ethernet "
                "there is no remote cycle start: leave out --unsafe and press cycle start"
            )
        plan.program_path.write_text(plan.program.text, encoding="ascii")
        return _drip_feed_and_capture(plan, say, on_event)
    load_program(plan, say)
    source = f"tcp://{plan.haas}:{plan.dprnt_port}" if plan.share is not None else plan.haas
    prompted = threading.Event()

    def status(message: str) -> None:
        if message.startswith("listening") and not prompted.is_set():
            prompted.set()
            say(
                f"waiting for cycle start: run {plan.program.name} on the control "
                f"(capturing {grid.size} points from {source})"
            )
        elif not message.startswith("listening"):
            say(message)

    return capture(
        source,
        grid,
        plan.points,
        baudrate=plan.baud,
        resume=plan.resume,
        idle_timeout=plan.idle_timeout,
        on_event=on_event,
        on_status=status,
        stop=stop,
    )


class _Tap:
    """A port whose received bytes are also handed to ``sink`` (DPRNT capture while the
    drip-feed reads the control's flow-control bytes from the same port)."""

    def __init__(self, port: PortStream, sink: Callable[[bytes], None]) -> None:
        self._port = port
        self._sink = sink

    def read(self, max_bytes: int) -> bytes:
        data = self._port.read(max_bytes)
        self._sink(data)
        return data

    def read_nowait(self, max_bytes: int) -> bytes:
        data = self._port.read_nowait(max_bytes)
        if data:
            self._sink(data)
        return data

    def write(self, data: bytes) -> None:
        self._port.write(data)

    def drain(self) -> None:
        self._port.drain()

    def set_timeout(self, timeout: float | None) -> None:
        self._port.set_timeout(timeout)

    def close(self) -> None:
        self._port.close()


def _drip_feed_and_capture(
    plan: MeasurePlan, say: Callable[[str], None], on_event: Callable[[MatchEvent], None]
) -> CaptureReport:
    from opendnc.haas.dnc import stream_program
    from opendnc.transport import open_stream

    grid = plan.program.grid
    writer = PointsWriter(plan.points, grid, resume=plan.resume)
    done = threading.Event()
    session = CaptureSession(grid, writer, on_event=on_event, done=done.set)
    framer = DprntLineFramer()

    def sink(data: bytes) -> None:
        framer.feed(data)
        for event in framer.events():
            if isinstance(event, FramedLine):  # an over-long line is dropped, never a point
                parsed = parse_line(event.text)
                session.feed(CapturedLine(datetime.now(UTC), event.text, parsed.fields))

    try:
        port = open_stream(plan.haas, plan.baud, timeout=0.1)
        try:
            say(f"drip-feeding {plan.program.name} on {plan.haas} (DNC: the machine moves)")
            stream_program(_Tap(port, sink), plan.program_path, baud=plan.baud, safe_mode=False)
            say("program sent; reading the last points")
            quiet_since = datetime.now(UTC)
            port.set_timeout(0.1)  # the drip-feed left its own
            while not done.is_set():
                try:
                    data = port.read(4096)
                except TransportTimeout:
                    data = b""
                except PeerClosed:
                    session.report.reason = "the port closed"
                    break
                if data:
                    sink(data)
                    quiet_since = datetime.now(UTC)
                    continue
                quiet = (datetime.now(UTC) - quiet_since).total_seconds()
                if plan.idle_timeout is not None and quiet > plan.idle_timeout:
                    session.report.reason = f"no line for {plan.idle_timeout:g} s"
                    break
        finally:
            port.close()
    finally:
        writer.close()
    report = session.report
    report.missing = session.matcher.missing()
    report.captured = len(session.matcher.values)
    return report
