"""asyncio drivers of the tape engine: the same send, drip-feed and punch receive as
:mod:`opendnc.tape.serial_io`, over a stream reader and writer (a serial device server
reached over TCP, say). The decisions are the same sans-IO objects':
:class:`~opendnc.haas.dnc_engine.DncRun` over a :class:`~opendnc.tape.feed.TapeFeed`, and
:class:`~opendnc.tape.session.PunchReceiver`.
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import Callable
from pathlib import Path

from opendnc.errors import TransportError
from opendnc.haas.dnc_engine import DncEvent, DncRun, Drain, Send, Wait
from opendnc.tape.codes import Codec
from opendnc.tape.profiles import Profile
from opendnc.tape.serial_io import (
    READ_SIZE,
    Incoming,
    Progress,
    TapeReport,
    prepare_send,
    tape_report,
)
from opendnc.tape.session import PunchReceiver, Received


async def send_program_async(
    reader: asyncio.StreamReader,
    writer: asyncio.StreamWriter,
    path: Path,
    profile: Profile,
    *,
    drip_feed: bool = False,
    from_line: int = 1,
    retract: bool = True,
    chunk: int | None = None,
    xoff_timeout: float = 60.0,
    wait_dc1: bool | None = None,
    text_check: bool = True,
    codec: Codec | None = None,
    safe_mode: bool = True,
    progress: Progress | None = None,
    on_event: Callable[[DncEvent], None] | None = None,
    keep: bytearray | None = None,
) -> TapeReport:
    """:func:`opendnc.tape.serial_io.send_program` over asyncio streams."""
    feed, config = prepare_send(
        path,
        profile,
        drip_feed=drip_feed,
        from_line=from_line,
        retract=retract,
        chunk=chunk,
        xoff_timeout=xoff_timeout,
        wait_dc1=wait_dc1,
        text_check=text_check,
        codec=codec,
        safe_mode=safe_mode,
    )
    run = DncRun(feed, config, progress=progress, on_event=on_event)
    incoming = Incoming()
    news = asyncio.Event()

    async def read_control() -> None:
        while data := await reader.read(READ_SIZE):
            run.incoming(incoming.split(data))
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
        raise TransportError(f"link failed during the send: {exc}") from exc
    finally:
        reading.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await reading
        feed.close()
    if keep is not None:
        keep += incoming.kept
    return tape_report(run, feed)


async def receive_record_async(
    reader: asyncio.StreamReader,
    profile: Profile,
    *,
    timeout: float | None = 60.0,
    quiet: float | None = None,
    quiet_ends: bool = False,
    codec: Codec | None = None,
    already: bytes = b"",
) -> Received:
    """:func:`opendnc.tape.serial_io.receive_record` over an asyncio stream reader."""
    receiver = PunchReceiver(
        profile, codec=codec, start_timeout=timeout, quiet=quiet, quiet_ends=quiet_ends
    )
    receiver.receive_data(already)
    serial, deadline = -1, float("inf")
    while not receiver.finished:
        timer = receiver.timer
        if timer is not None and timer.serial != serial:
            serial, deadline = timer.serial, time.monotonic() + timer.seconds
        remaining = None if timer is None else deadline - time.monotonic()
        if remaining is not None and remaining <= 0:
            receiver.timed_out()
            continue
        try:
            data = await asyncio.wait_for(reader.read(READ_SIZE), remaining)
        except TimeoutError:
            continue
        except OSError as exc:
            raise TransportError(f"link failed during the receive: {exc}") from exc
        if not data:
            receiver.peer_closed()
        receiver.receive_data(data)
    return receiver.result()
