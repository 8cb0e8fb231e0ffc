"""Drivers that run the XModem engines over real I/O: blocking and asyncio.

Both drivers run one pump (``_pump``, a generator with no I/O of its own) around the same
sans-IO engine: write what the engine wants to send, hand its events to a callback, feed it
what the peer sent, and tell it when its timer ran out or the link closed. The pump owns the
clock (the engines never read one); a driver only performs the write, read or pause it asks
for, blocking or with ``await``.

Blocking use::

    stream = SerialStream("/dev/ttyUSB0", 115200, timeout=0.1)
    done = send(stream, program, mode=Mode.CHECKSUM, progress=lambda n, total: ...)

The blocking driver polls with a fixed short read timeout instead of changing the timeout for
every wait, because pyserial re-applies all port settings whenever the timeout changes.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable, Generator
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


class _Pause(float):
    """A pump step: wait this many seconds without reading (a timer that does not listen)."""


# The pump writes through the callable it is given and yields when it must wait: a read
# timeout in seconds (it is sent the bytes read: ``None`` if nothing came, ``b""`` if the link
# closed) or a :class:`_Pause`. One yield per block keeps the driver's share of a block small.
_Pump = Generator[float, "bytes | None", Completed]


def _pump(
    engine: Engine, on_event: EventHandler | None, clock: Clock, write: Callable[[bytes], object]
) -> _Pump:
    """The driver logic, shared by both drivers: what to write, when to read, events, timers."""
    deadline = _Deadline(clock)
    # bound once: this loop turns once per block, and lookups are a visible share of it
    data_to_send, remaining_for, prepare = engine.data_to_send, deadline.remaining, engine.prepare
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
            yield _Pause(remaining)
            continue
        data = yield remaining
        if data:
            engine.receive_data(data)
        elif data is not None:
            engine.peer_closed()


def _cancel(engine: Engine) -> bytes:
    """Cancel ``engine`` locally; the CAN CAN CAN it wants on the wire."""
    engine.cancel()
    return engine.data_to_send()


def run_blocking(
    engine: Engine,
    stream: ByteStream,
    *,
    on_event: EventHandler | None = None,
    clock: Clock = time.monotonic,
    poll: float = POLL,
) -> Completed:
    """Run ``engine`` to its end over a blocking ``stream``; raise its typed error on failure.

    Reads poll every ``poll`` seconds whatever the engine's timer (see the module doc).
    Ctrl-C cancels the session on the wire (CAN CAN CAN) before it propagates.
    """
    stream.set_timeout(poll)
    pump = _pump(engine, on_event, clock, stream.write)
    read, advance = stream.read, pump.send
    try:
        step = next(pump)
        while True:
            if type(step) is _Pause:
                time.sleep(step)
                step = advance(None)
                continue
            try:
                got: bytes | None = read(READ_SIZE) or None
            except TransportTimeout:
                got = None
            except PeerClosed:
                got = b""
            step = advance(got)
    except StopIteration as done:
        result: Completed = done.value
        return result
    except KeyboardInterrupt:
        if out := _cancel(engine):
            stream.write(out)
        raise
    finally:
        pump.close()


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
    pump = _pump(engine, on_event, clock, writer.write)
    try:
        step = next(pump)
        while True:
            await writer.drain()  # what the pump wrote leaves before we wait
            if type(step) is _Pause:
                await asyncio.sleep(step)
                step = pump.send(None)
                continue
            try:
                got: bytes | None = await asyncio.wait_for(reader.read(READ_SIZE), step)
            except TimeoutError:
                got = None
            except (ConnectionError, OSError):
                got = b""
            step = pump.send(got)
    except StopIteration as done:
        await writer.drain()
        result: Completed = done.value
        return result
    except asyncio.CancelledError:
        if out := _cancel(engine):
            writer.write(out)
        raise
    finally:
        pump.close()


def _sender(
    data: bytes,
    mode: Mode,
    config: SenderConfig | None,
    progress: Progress | None,
    on_event: EventHandler | None,
) -> tuple[XmodemSender, EventHandler | None]:
    """The engine and event handler of one send (the same for both drivers)."""
    handler = on_event
    if progress is not None:  # else nothing to translate: skip a call per event

        def handler(event: Event) -> None:
            if isinstance(event, BlockDone):
                progress(event.done, event.total)
            if on_event is not None:
                on_event(event)

    return XmodemSender(data, mode, config, block_events=handler is not None), handler


def _receiver(
    sink: BinaryIO | Callable[[bytes], object],
    mode: Mode,
    config: ReceiverConfig | None,
    progress: Progress | None,
    on_event: EventHandler | None,
) -> tuple[XmodemReceiver, EventHandler]:
    """The engine and event handler of one receive (the same for both drivers)."""
    write = sink.write if hasattr(sink, "write") else sink
    received = 0

    def handler(event: Event) -> None:
        nonlocal received
        if isinstance(event, DataReceived):
            write(event.data)
            received += len(event.data)
            if progress is not None:
                progress(received, None)
        if on_event is not None:
            on_event(event)

    return XmodemReceiver(mode, config), handler


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
    engine, handler = _sender(data, mode, config, progress, on_event)
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
    engine, handler = _receiver(sink, mode, config, progress, on_event)
    return run_blocking(engine, stream, on_event=handler)


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
    engine, handler = _sender(data, mode, config, progress, on_event)
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
    engine, handler = _receiver(sink, mode, config, progress, on_event)
    return await run_async(engine, reader, writer, on_event=handler)
