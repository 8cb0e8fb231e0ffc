"""The asyncio drip-feed stops within one chunk of the control's DC3, through its public API.

The streams are asyncio's own reader and writer over an in-memory transport: the "control"
answers inside ``write()``, so the DC3 is available to the driver at an exact byte count and
the overrun can be counted without any timing assumption.  Only ``stream_program_async`` and
its documented arguments are used, so the test holds for any internal structure of the driver.
"""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

import pytest

from opendnc.haas.dnc import DncConfig, DncEvent, Paused, Resumed, stream_program_async

XON, XOFF = b"\x11", b"\x13"


class Control(asyncio.Transport):
    """The wire as the control sees it: records writes, answers DC3 at a byte count."""

    def __init__(self, reader: asyncio.StreamReader, xoff_at: int) -> None:
        super().__init__()
        self.reader = reader
        self.xoff_at = xoff_at
        self.received = bytearray()
        self.at_xoff: int | None = None  # bytes received when the DC3 went out
        self.writes = 0
        self._closing = False

    def write(self, data: bytes | bytearray | memoryview) -> None:
        self.received += data
        self.writes += 1
        if self.at_xoff is None and len(self.received) >= self.xoff_at:
            self.at_xoff = len(self.received)
            self.reader.feed_data(XOFF)  # in the driver's input before write() returns

    def is_closing(self) -> bool:
        return self._closing

    def close(self) -> None:
        self._closing = True

    def get_extra_info(self, name: str, default: Any = None) -> Any:
        return default


def program(path: Path, blocks: int) -> bytes:
    text = "%\nO01234 (STOP TEST)\n" + "".join(
        f"G01 X{i}. Y{i % 7}. F100.\n" for i in range(blocks)
    )
    data = (text + "M30\n%\n").encode("ascii")
    path.write_bytes(data)
    return data


@pytest.mark.parametrize("chunk", [1, 16, 64, 256])
def test_dc3_stops_the_writer_within_one_chunk(tmp_path: Path, chunk: int) -> None:
    source = tmp_path / "O01234.nc"
    data = program(source, 400)
    xoff_at = len(data) // 3

    async def scenario() -> tuple[Control, list[DncEvent], int, int]:
        loop = asyncio.get_running_loop()
        reader = asyncio.StreamReader()
        protocol = asyncio.StreamReaderProtocol(reader)
        control = Control(reader, xoff_at)
        protocol.connection_made(control)
        writer = asyncio.StreamWriter(control, protocol, reader, loop)
        events: list[DncEvent] = []
        paused = asyncio.Event()

        def on_event(event: DncEvent) -> None:
            events.append(event)
            if isinstance(event, Paused):
                paused.set()

        config = DncConfig(chunk=chunk, linger=0.0, xoff_timeout=30.0)
        run = asyncio.create_task(
            stream_program_async(
                reader, writer, source, safe_mode=False, config=config, on_event=on_event
            )
        )
        await asyncio.wait_for(paused.wait(), 10)
        # Give the driver many turns of the loop: a writer that ignored the DC3 would use them.
        for _ in range(200):
            await asyncio.sleep(0)
        held = len(control.received)
        writes_held = control.writes
        # everything written after the DC3 was available: at most the rest of one chunk
        assert control.at_xoff is not None
        overrun = held - control.at_xoff
        assert 0 <= overrun < chunk, f"{overrun} bytes written after DC3 (chunk {chunk})"
        await asyncio.sleep(0.05)  # and some wall time (the driver may wait on a timer)
        assert len(control.received) == held, "bytes were written while the control held DC3"
        assert control.writes == writes_held
        reader.feed_data(XON)
        report = await asyncio.wait_for(run, 10)
        assert report.bytes_sent == len(data)
        assert report.xoffs == 1
        assert report.xons == 1
        writer.close()
        protocol.connection_lost(None)
        return control, events, held, chunk

    control, events, held, _ = asyncio.run(scenario())
    assert bytes(control.received) == data  # nothing lost or repeated around the pause
    assert [type(e) for e in events] == [Paused, Resumed]
    assert events[0].sent == held


def test_xoff_before_the_first_byte_holds_everything(tmp_path: Path) -> None:
    """A DC3 already waiting when the run starts: not one chunk goes out until the DC1."""
    source = tmp_path / "O01234.nc"
    data = program(source, 50)

    async def scenario() -> int:
        loop = asyncio.get_running_loop()
        reader = asyncio.StreamReader()
        protocol = asyncio.StreamReaderProtocol(reader)
        control = Control(reader, xoff_at=10**9)
        protocol.connection_made(control)
        writer = asyncio.StreamWriter(control, protocol, reader, loop)
        reader.feed_data(XOFF)
        config = DncConfig(chunk=16, linger=0.0, xoff_timeout=30.0)
        run = asyncio.create_task(
            stream_program_async(reader, writer, source, safe_mode=False, config=config)
        )
        for _ in range(200):
            await asyncio.sleep(0)
        await asyncio.sleep(0.05)
        early = len(control.received)
        reader.feed_data(XON)
        await asyncio.wait_for(run, 10)
        writer.close()
        protocol.connection_lost(None)
        assert bytes(control.received) == data
        return early

    # The driver may hand out the first chunk before its reader task has run once; never more.
    assert asyncio.run(scenario()) <= 16
