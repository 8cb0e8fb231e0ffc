"""asyncio drivers of the tape engine: the same send, drip-feed and punch receive as
:mod:`opendnc.tape.serial_io`, over a stream reader and writer (a serial device server
reached over TCP, say). The decisions are the same sans-IO objects':
:class:`~opendnc.haas.dnc_engine.DncRun` over a :class:`~opendnc.tape.feed.TapeFeed`, run by
:func:`~opendnc.haas.dnc_drivers.run_on_streams`, and a
:class:`~opendnc.tape.session.PunchReceiver` whose waits come from
:func:`~opendnc.tape.session.receive_steps`; this module only reads and writes.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable
from pathlib import Path
from typing import Unpack

from opendnc.errors import TransportError
from opendnc.haas.dnc_drivers import READ_SIZE, run_on_streams
from opendnc.haas.dnc_engine import DncEvent
from opendnc.tape.codes import Codec
from opendnc.tape.profiles import Profile
from opendnc.tape.serial_io import (
    Incoming,
    Progress,
    SendOptions,
    TapeReport,
    prepare_send,
    tape_report,
)
from opendnc.tape.session import PunchReceiver, Received, receive_steps


async def send_program_async(
    reader: asyncio.StreamReader,
    writer: asyncio.StreamWriter,
    path: Path,
    profile: Profile,
    *,
    progress: Progress | None = None,
    on_event: Callable[[DncEvent], None] | None = None,
    keep: bytearray | None = None,
    **options: Unpack[SendOptions],
) -> TapeReport:
    """:func:`opendnc.tape.serial_io.send_program` over asyncio streams."""
    feed, config = prepare_send(path, profile, **options)
    incoming = Incoming()
    run = await run_on_streams(
        feed,
        config,
        reader,
        writer,
        what="send",
        split=incoming.split,
        progress=progress,
        on_event=on_event,
    )
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
    steps = receive_steps(receiver, time.monotonic)
    try:
        wait = next(steps)
        while True:
            try:
                data: bytes | None = await asyncio.wait_for(reader.read(READ_SIZE), wait)
            except TimeoutError:
                data = None
            except OSError as exc:
                raise TransportError(f"link failed during the receive: {exc}") from exc
            wait = steps.send(data)
    except StopIteration as done:
        record: Received = done.value
        return record
