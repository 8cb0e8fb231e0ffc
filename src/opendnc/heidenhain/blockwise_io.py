"""Running the blockwise engines over a serial port (blocking), for the CLI and tests."""

from __future__ import annotations

import time
from dataclasses import dataclass

from opendnc.errors import InputError, TransportTimeout
from opendnc.heidenhain.blockwise import (
    DEFAULT_SETTINGS,
    BlockReceiver,
    BlockSender,
    BlockwiseSettings,
    FileReceived,
    FileRequested,
    FileSent,
    TransferFailed,
    join_lines,
    split_lines,
)
from opendnc.transport.base import ByteStream
from opendnc.transport.marks import LineData, line_reader

__all__ = ["BlockLine", "open_block_line", "receive_file", "send_file"]

POLL = 0.02


@dataclass(frozen=True, slots=True)
class BlockLine:
    """Port settings of the blockwise protocol (default 9600 baud 7E1, as on older units)."""

    url: str
    baud: int = 9600
    parity: str = "E"
    bytesize: int = 7
    stopbits: float = 1
    flow: str = "none"
    mark_errors: bool = True
    """Have the port mark characters failing their parity check, so their block is refused
    (POSIX devices; docs/lsv2-serial.md, "Parity errors")."""


def open_block_line(line: BlockLine) -> ByteStream:
    """Open the port (a pty gets 8N1: it has neither parity nor a 7-bit mode)."""
    from opendnc.lsv2.serial_stream import line_parity
    from opendnc.transport import open_stream

    parity = line_parity(line.url, line.parity)
    bytesize = 8 if parity == "N" and line.parity.upper() != "N" else line.bytesize
    return open_stream(
        line.url,
        line.baud,
        timeout=POLL,
        parity=parity,
        bytesize=bytesize,
        stopbits=line.stopbits,
        # DC1/DC3 are the protocol's own flow control: never the port's
        flow="rtscts" if line.flow == "rtscts" else "none",
        mark_errors=line.mark_errors,
    )


def _pump(stream: ByteStream, engine: BlockSender | BlockReceiver, serve: bytes | None) -> object:
    stream.set_timeout(POLL)
    read = line_reader(stream)
    while True:
        out = engine.data_to_send()
        if out:
            stream.write(out)
        while (event := engine.next_event()) is not None:
            if isinstance(event, FileRequested) and isinstance(engine, BlockSender):
                engine.serve(None if serve is None else split_lines(serve), time.monotonic())
                continue
            if isinstance(event, TransferFailed):
                raise event.error
            out = engine.data_to_send()
            if out:
                stream.write(out)
            return event
        try:
            got = read(4096)
        except TransportTimeout:
            got = LineData(b"")
        now = time.monotonic()
        engine.receive_data(got.data, now, got.errors)
        engine.tick(now)


def send_file(
    stream: ByteStream,
    name: str,
    data: bytes,
    *,
    wait_request: bool = False,
    settings: BlockwiseSettings = DEFAULT_SETTINGS,
) -> FileSent:
    """Send ``data`` as file ``name``: pushed with an H header, or served on a K request."""
    lines = split_lines(data)
    sender = BlockSender(None if wait_request else name, lines, settings=settings)
    sender.start(time.monotonic())
    event = _pump(stream, sender, data if wait_request else None)
    assert isinstance(event, FileSent)
    return event


def receive_file(
    stream: ByteStream,
    request: str | None = None,
    *,
    line_end: bytes = b"\r\n",
    settings: BlockwiseSettings = DEFAULT_SETTINGS,
) -> tuple[str, bytes]:
    """Receive one file (pushed, or asked for by name); returns its name and content."""
    receiver = BlockReceiver(request, settings=settings)
    receiver.start(time.monotonic())
    event = _pump(stream, receiver, None)
    assert isinstance(event, FileReceived)
    name = event.name.replace("\\", "/").rsplit("/", 1)[-1].rsplit(":", 1)[-1]
    if not name or name in (".", ".."):
        raise InputError(f"the control sent an unusable file name {event.name!r}")
    return name, join_lines(event.lines, line_end)
