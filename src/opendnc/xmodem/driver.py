"""Drivers that run the XModem engines over real I/O: blocking and asyncio.

Both drivers are thin pumps around the same sans-IO engine: write what the engine wants to
send, hand its events to a callback, feed it what the peer sent, and tell it when its timer
ran out or the link closed. They own the clock; the engines never read one.

Blocking use::

    stream = SerialStream("/dev/ttyUSB0", 115200, timeout=0.1)
    done = send(stream, program, mode=Mode.CHECKSUM, progress=lambda n, total: ...)

The blocking driver polls with a fixed short read timeout instead of changing the timeout for
every wait, because pyserial re-applies all port settings whenever the timeout changes.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable
from typing import BinaryIO

from opendnc.errors import LocalProtocolError, PeerClosed, TransportTimeout
from opendnc.transport.base import ByteStream
from opendnc.xmodem.events import BlockDone, Completed, DataReceived, Event
from opendnc.xmodem.framing import Mode
from opendnc.xmodem.receiver import ReceiverConfig, XmodemReceiver
from opendnc.xmodem.sender import SenderConfig, XmodemSender

Engine = XmodemSender | XmodemReceiver
EventHandler = Callable[[Event], None]
# progress(done_bytes, total_bytes); total is None while receiving (XModem sends no size)
Progress = Callable[[int, int | None], None]
Clock = Callable[[], float]

READ_SIZE = 4096  # more than one 1K block, so one read usually carries a whole block
POLL = 0.05  # read timeout of the blocking driver; the granularity of engine timers


class _Deadline:
    """Turns the engine's timer into an absolute deadline on the driver's clock."""

    def __init__(self, clock: Clock) -> None:
        self._clock = clock
        self._serial = -1
        self._at = float("inf")

    def remaining(self, engine: Engine) -> float:
        timer = engine.timer
        now = self._clock()
        if timer is None:
            self._serial, self._at = -1, float("inf")
        elif timer.serial != self._serial:
            self._serial, self._at = timer.serial, now + timer.seconds
        return self._at - now


def _dispatch(engine: Engine, on_event: EventHandler | None) -> None:
    """Hand the engine's pending events to the callback (or drop them)."""
    if on_event is not None:
        while (event := engine.next_event()) is not None:
            on_event(event)
    else:
        while engine.next_event() is not None:
            pass


def _outcome(engine: Engine) -> Completed:
    """The Completed event of a finished engine, or its typed error raised."""
    if engine.error is not None:
        raise engine.error
    if engine.result is None:
        raise LocalProtocolError("the XModem engine has not finished")
    return engine.result


def run_blocking(
    engine: Engine,
    stream: ByteStream,
    *,
    on_event: EventHandler | None = None,
    clock: Clock = time.monotonic,
    poll: float = POLL,
) -> Completed:
    """Run ``engine`` to its end over a blocking ``stream``; raise its typed error on failure.

    Ctrl-C cancels the session on the wire (CAN CAN CAN) before it propagates.
    """
    deadline = _Deadline(clock)
    stream.set_timeout(poll)
    # bound once: this loop turns once per block, and lookups are a visible share of it
    write, read, receive_data = stream.write, stream.read, engine.receive_data
    data_to_send, remaining_for, prepare = engine.data_to_send, deadline.remaining, engine.prepare
    try:
        while True:
            out = data_to_send()
            if engine.finished:
                # the final events (the last block, Completed/Failed) are handled before the
                # last bytes go out: the sender hears "complete" only once the file is stored
                _dispatch(engine, on_event)
                if out:
                    write(out)
                return _outcome(engine)
            # mid-transfer, answer first and handle events (file writes, progress) after:
            # the peer gets on with the next block while we do our bookkeeping
            if out:
                write(out)
            if engine.has_events:
                _dispatch(engine, on_event)
            prepare()
            remaining = remaining_for(engine)
            if remaining <= 0:
                engine.timed_out()
                continue
            timer = engine.timer
            if timer is not None and not timer.listen:
                time.sleep(remaining)
                continue
            try:
                data = read(READ_SIZE)
            except TransportTimeout:
                continue
            except PeerClosed:
                engine.peer_closed()
                continue
            receive_data(data)
    except KeyboardInterrupt:
        engine.cancel()
        out = engine.data_to_send()
        if out:
            stream.write(out)
        raise


async def run_async(
    engine: Engine,
    reader: asyncio.StreamReader,
    writer: asyncio.StreamWriter,
    *,
    on_event: EventHandler | None = None,
    clock: Clock = time.monotonic,
) -> Completed:
    """Run ``engine`` to its end over asyncio streams; raise its typed error on failure.

    Cancelling the task cancels the session on the wire (CAN CAN CAN) first.
    """
    deadline = _Deadline(clock)
    try:
        while True:
            out = engine.data_to_send()
            if engine.finished:
                _dispatch(engine, on_event)  # final events before the last bytes, as above
                if out:
                    writer.write(out)
                    await writer.drain()
                return _outcome(engine)
            if out:
                writer.write(out)
                await writer.drain()
            _dispatch(engine, on_event)
            engine.prepare()
            remaining = deadline.remaining(engine)
            if remaining <= 0:
                engine.timed_out()
                continue
            if engine.timer is not None and not engine.timer.listen:
                await asyncio.sleep(remaining)
                continue
            try:
                data = await asyncio.wait_for(reader.read(READ_SIZE), remaining)
            except TimeoutError:
                continue
            except (ConnectionError, OSError):
                engine.peer_closed()
                continue
            if data:
                engine.receive_data(data)
            else:
                engine.peer_closed()
    except asyncio.CancelledError:
        engine.cancel()
        out = engine.data_to_send()
        if out:
            writer.write(out)
        raise


def _sender_events(progress: Progress | None, on_event: EventHandler | None) -> EventHandler | None:
    if progress is None:
        return on_event  # nothing to translate: skip a call per event

    def handle(event: Event) -> None:
        if isinstance(event, BlockDone):
            progress(event.done, event.total)
        if on_event is not None:
            on_event(event)

    return handle


def _receiver_events(
    sink: Callable[[bytes], object], progress: Progress | None, on_event: EventHandler | None
) -> EventHandler:
    received = 0

    def handle(event: Event) -> None:
        nonlocal received
        if isinstance(event, DataReceived):
            sink(event.data)
            received += len(event.data)
            if progress is not None:
                progress(received, None)
        if on_event is not None:
            on_event(event)

    return handle


def send(
    stream: ByteStream,
    data: bytes,
    *,
    mode: Mode = Mode.ONE_K,
    config: SenderConfig | None = None,
    progress: Progress | None = None,
    on_event: EventHandler | None = None,
) -> Completed:
    """Send ``data`` over ``stream`` as one XModem session (blocking)."""
    handler = _sender_events(progress, on_event)
    engine = XmodemSender(data, mode, config, block_events=handler is not None)
    return run_blocking(engine, stream, on_event=handler)


def receive(
    stream: ByteStream,
    sink: BinaryIO | Callable[[bytes], object],
    *,
    mode: Mode = Mode.CRC,
    config: ReceiverConfig | None = None,
    progress: Progress | None = None,
    on_event: EventHandler | None = None,
) -> Completed:
    """Receive one XModem session from ``stream``, writing the file bytes to ``sink``.

    ``sink`` is a binary file or a callable taking bytes. On failure the typed error is raised
    and ``sink`` may hold a partial file: :func:`opendnc.xmodem.files.receive_file` writes to a
    temporary file and renames it only on success.
    """
    write = sink.write if hasattr(sink, "write") else sink
    engine = XmodemReceiver(mode, config)
    return run_blocking(engine, stream, on_event=_receiver_events(write, progress, on_event))


async def send_async(
    reader: asyncio.StreamReader,
    writer: asyncio.StreamWriter,
    data: bytes,
    *,
    mode: Mode = Mode.ONE_K,
    config: SenderConfig | None = None,
    progress: Progress | None = None,
    on_event: EventHandler | None = None,
) -> Completed:
    """Send ``data`` as one XModem session over asyncio streams."""
    handler = _sender_events(progress, on_event)
    engine = XmodemSender(data, mode, config, block_events=handler is not None)
    return await run_async(engine, reader, writer, on_event=handler)


async def receive_async(
    reader: asyncio.StreamReader,
    writer: asyncio.StreamWriter,
    sink: BinaryIO | Callable[[bytes], object],
    *,
    mode: Mode = Mode.CRC,
    config: ReceiverConfig | None = None,
    progress: Progress | None = None,
    on_event: EventHandler | None = None,
) -> Completed:
    """Receive one XModem session over asyncio streams, writing the file bytes to ``sink``."""
    write = sink.write if hasattr(sink, "write") else sink
    engine = XmodemReceiver(mode, config)
    handler = _receiver_events(write, progress, on_event)
    return await run_async(engine, reader, writer, on_event=handler)
