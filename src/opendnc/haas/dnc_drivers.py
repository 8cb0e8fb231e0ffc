"""The two drivers of a :class:`~opendnc.haas.dnc_engine.DncRun`, for every engine that runs one.

A run decides everything (when to write, how long to wait, when a DC3 has lasted too long);
a driver only carries out its steps on one kind of link:

* :func:`run_on_port` -- blocking, on a :class:`~opendnc.transport.base.PortStream` (or a URL
  it opens and closes);
* :func:`run_on_streams` -- asyncio, on a stream reader and writer.

The Haas drip-feed (:mod:`opendnc.haas.dnc`) and the tape engine's send and drip-feed
(:mod:`opendnc.tape.serial_io`, :mod:`opendnc.tape.aio`) go through these two and nothing
else: how a step is carried out is written once for every control and both kinds of link.
The engines differ only in what of the control's bytes the run hears (``split``): the Haas
run hears everything; the tape engine keeps a punch that follows a send for the next receive.
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import Callable

from opendnc.errors import PeerClosed, TransportError, TransportTimeout
from opendnc.haas.dnc_engine import (
    Clock,
    DncConfig,
    DncRun,
    Drain,
    EventHandler,
    FeedPosition,
    ProgramFeed,
    Progress,
    Send,
    Wait,
)
from opendnc.transport.base import PortStream

READ_SIZE = 4096  # the control sends flow bytes, a DPRNT line at most: any size will do

Split = Callable[[bytes], bytes]
"""What of the control's bytes the run hears (the rest is the caller's to keep)."""


def hear_all(data: bytes) -> bytes:
    """The :data:`Split` that hands the run every byte."""
    return data


def drive(run: DncRun, stream: PortStream, *, split: Split = hear_all) -> None:
    """Carry out ``run``'s steps on ``stream`` until it finishes (its read timeout changes)."""
    timeout: float | None = None
    while True:
        # look at the control's bytes before every write: a DC3 stops the next chunk
        try:
            run.incoming(split(stream.read_nowait(READ_SIZE)))
        except PeerClosed:
            run.link_closed()
        step = run.next_step()
        if isinstance(step, Send):
            # a stop inside a write leaves the control an unknown part of the chunk
            run.writing = True
            stream.write(step.data)
            if step.drain:
                stream.drain()
            run.writing = False
        elif isinstance(step, Wait):
            if step.seconds != timeout:
                timeout = step.seconds
                stream.set_timeout(timeout)
            try:
                run.incoming(split(stream.read(READ_SIZE)))
            except TransportTimeout:
                pass
            except PeerClosed:
                run.link_closed()
        elif isinstance(step, Drain):
            run.writing = True
            stream.drain()
            run.writing = False
        else:
            return


def run_on_port(
    feed: ProgramFeed,
    config: DncConfig,
    port: str | PortStream,
    open_port: Callable[[str], PortStream],
    *,
    split: Split = hear_all,
    progress: Progress | None = None,
    on_event: EventHandler | None = None,
    clock: Clock = time.monotonic,
    skip: bytes = b"",
    stopped: Callable[[FeedPosition | None], None] | None = None,
    waiting: Callable[[], None] | None = None,
) -> DncRun:
    """Run ``feed`` to its end on ``port``: a URL or device name (opened with ``open_port``,
    closed at the end) or an open stream (left open). ``feed`` is closed whatever happens;
    the finished run is returned for its report. ``skip``: the bytes a continuation leaves
    out (:class:`~opendnc.haas.dnc_engine.FeedPosition`); ``stopped`` is told where a run
    that ends with an error stopped (None: not exactly known); ``waiting`` is asked before
    each wait for the control and may raise to stop the run there."""
    owned = isinstance(port, str)
    try:
        stream = open_port(port) if isinstance(port, str) else port
    except BaseException:
        feed.close()
        raise
    try:
        run = DncRun(
            feed,
            config,
            clock=clock,
            progress=progress,
            on_event=on_event,
            skip=skip,
            waiting=waiting,
        )
        try:
            drive(run, stream, split=split)
        except BaseException:
            if stopped is not None:
                stopped(run.position())
            raise
    finally:
        feed.close()
        if owned:
            stream.close()
    return run


async def run_on_streams(
    feed: ProgramFeed,
    config: DncConfig,
    reader: asyncio.StreamReader,
    writer: asyncio.StreamWriter,
    *,
    what: str,
    split: Split = hear_all,
    progress: Progress | None = None,
    on_event: EventHandler | None = None,
) -> DncRun:
    """:func:`run_on_port` over asyncio streams (``writer`` is left open).

    A reader task hands the control's bytes to the run as they come; the writer sends one
    chunk at a time and yields in between, so a DC3 stops it before the next chunk. A failed
    link is a :class:`TransportError` naming ``what`` was under way (``"send"``, say).
    """
    news = asyncio.Event()
    try:
        run = DncRun(feed, config, progress=progress, on_event=on_event)
    except BaseException:
        feed.close()
        raise

    async def read_control() -> None:
        while data := await reader.read(READ_SIZE):
            run.incoming(split(data))
            news.set()
        run.link_closed()
        news.set()

    reading = asyncio.create_task(read_control())
    try:
        while True:
            step = run.next_step()
            if isinstance(step, Send):
                writer.write(step.data)
                await writer.drain()
                await asyncio.sleep(0)  # let the reader task see a DC3 first
            elif isinstance(step, Wait):
                news.clear()
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(news.wait(), step.seconds)
            elif isinstance(step, Drain):
                await writer.drain()
            else:
                break
    except OSError as exc:
        raise TransportError(f"link failed during the {what}: {exc}") from exc
    finally:
        reading.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await reading
        feed.close()
    return run
