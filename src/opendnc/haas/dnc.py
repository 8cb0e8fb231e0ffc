"""Drip-feed (DNC) a program to a Haas over RS-232, with XON/XOFF done by us.

The decisions live in the sans-IO engine, :mod:`opendnc.haas.dnc_engine` (its names are
re-exported here). This module holds its two entry points; they check the program, then hand
the run to the drivers every engine shares (:mod:`opendnc.haas.dnc_drivers`):

* :func:`stream_program` -- blocking, over any port :func:`opendnc.transport.open_stream`
  opens (a device, ``socket://`` or ``tcp://`` to a serial server, ``rfc2217://``) or an
  open :class:`~opendnc.transport.base.PortStream`;
* :func:`stream_program_async` -- asyncio, over a stream reader and writer.

Drip-feeding makes the machine move, so both refuse with
:class:`~opendnc.errors.SafetyLockError` unless ``safe_mode=False``.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable
from pathlib import Path

from opendnc.errors import SafetyLockError
from opendnc.haas.dnc_drivers import run_on_port, run_on_streams
from opendnc.haas.dnc_engine import (
    POLL,
    XOFF,
    XON,
    Clock,
    DncConfig,
    DncEvent,
    DncReport,
    DncRun,
    DncStreamer,
    Drain,
    EventHandler,
    FeedPosition,
    Finish,
    Flow,
    Paused,
    ProgramFeed,
    Progress,
    Resumed,
    Send,
    Step,
    Wait,
)
from opendnc.nctext import check_program_file
from opendnc.transport.base import PortStream
from opendnc.transport.urls import open_stream

__all__ = [
    "POLL",
    "WRITE_TIMEOUT",
    "XOFF",
    "XON",
    "Clock",
    "DncConfig",
    "DncEvent",
    "DncReport",
    "DncRun",
    "DncStreamer",
    "Drain",
    "EventHandler",
    "FeedPosition",
    "Finish",
    "Flow",
    "Paused",
    "ProgramFeed",
    "Progress",
    "Resumed",
    "Send",
    "Step",
    "Wait",
    "open_dnc_port",
    "stream_program",
    "stream_program_async",
]

WRITE_TIMEOUT = 30.0  # seconds a write may wait: a held CTS ends in a clear error, not a hang


def open_dnc_port(
    url: str,
    baud: int = 9600,
    *,
    parity: str = "N",
    bytesize: int = 8,
    stopbits: float = 1,
    flow: Flow = Flow.XONXOFF,
) -> PortStream:
    """Open ``url`` for a drip-feed: XON/XOFF stays ours (never the driver's), RTS/CTS is
    the port's, reads wait :data:`POLL` at most and writes :data:`WRITE_TIMEOUT`."""
    return open_stream(
        url,
        baud,
        parity=parity,
        bytesize=bytesize,
        stopbits=stopbits,
        flow="rtscts" if flow is Flow.RTSCTS else "none",
        timeout=POLL,
        write_timeout=WRITE_TIMEOUT,
    )


def _prepare(
    path: Path,
    from_line: int,
    config: DncConfig,
    safe_mode: bool,
    resume: FeedPosition | None = None,
) -> ProgramFeed:
    if safe_mode:
        raise SafetyLockError(f"drip-feeding {path.name} (it runs on the machine)")
    if config.text_check:
        check_program_file(path, action="not drip-fed")
    return ProgramFeed(
        path,
        eob=config.eob,
        from_line=from_line,
        retract=config.retract,
        resume_at=resume.offset if resume is not None else None,
    )


def stream_program(
    port: str | PortStream,
    path: Path,
    *,
    from_line: int = 1,
    baud: int = 9600,
    parity: str = "N",
    bytesize: int = 8,
    stopbits: float = 1,
    config: DncConfig | None = None,
    safe_mode: bool = True,
    progress: Progress | None = None,
    on_event: EventHandler | None = None,
    clock: Clock = time.monotonic,
    resume: FeedPosition | None = None,
    stopped: Callable[[FeedPosition | None], None] | None = None,
    waiting: Callable[[], None] | None = None,
) -> DncReport:
    """Drip-feed ``path`` to a control in DNC mode over ``port``: a URL or device name
    (opened with :func:`open_dnc_port`, closed at the end) or an open stream (left open;
    its read timeout is changed).

    ``resume`` continues a run stopped at that position (the rest of its line and the lines
    after, no leader, no opening ``%``; ``from_line`` is then ignored); ``stopped`` is told
    where a run that ends with an error stopped, or None where that is not exactly known
    (docs/server.md#a-fenced-drip-feed); ``waiting`` is asked each time the run is about to
    wait for the control (held by XOFF, a line's delay) and may raise to stop it there.

    Raises :class:`SafetyLockError` while ``safe_mode`` is on (a DNC run moves the machine),
    :class:`TransportTimeout` when XOFF lasts longer than ``config.xoff_timeout`` or a write
    is held back longer than :data:`WRITE_TIMEOUT`, and :class:`TransportError` /
    :class:`PeerClosed` when the port fails.
    """
    cfg = config or DncConfig()
    feed = _prepare(path, from_line, cfg, safe_mode, resume)

    def open_port(url: str) -> PortStream:
        return open_dnc_port(
            url, baud, parity=parity, bytesize=bytesize, stopbits=stopbits, flow=cfg.flow
        )

    run = run_on_port(
        feed,
        cfg,
        port,
        open_port,
        progress=progress,
        on_event=on_event,
        clock=clock,
        skip=resume.written if resume is not None else b"",
        stopped=stopped,
        waiting=waiting,
    )
    return run.report()


async def stream_program_async(
    reader: asyncio.StreamReader,
    writer: asyncio.StreamWriter,
    path: Path,
    *,
    from_line: int = 1,
    config: DncConfig | None = None,
    safe_mode: bool = True,
    progress: Progress | None = None,
    on_event: EventHandler | None = None,
) -> DncReport:
    """:func:`stream_program` over asyncio streams (e.g. a serial server reached over TCP);
    see :func:`~opendnc.haas.dnc_drivers.run_on_streams`."""
    cfg = config or DncConfig()
    feed = _prepare(path, from_line, cfg, safe_mode)
    run = await run_on_streams(
        feed, cfg, reader, writer, what="drip-feed", progress=progress, on_event=on_event
    )
    return run.report()
