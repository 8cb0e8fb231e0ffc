"""Blocking and asyncio drivers over real ptys and loopback TCP, our engine on both ends."""

from __future__ import annotations

import asyncio
import io
import random
import threading
from collections.abc import Callable

import pytest

from opendnc.errors import DncError, PeerClosed, TransferError
from opendnc.transport import SerialStream
from opendnc.transport.fd import FdStream
from opendnc.xmodem.driver import receive, receive_async, send, send_async
from opendnc.xmodem.events import Completed
from opendnc.xmodem.framing import Mode
from opendnc.xmodem.receiver import ReceiverConfig
from tests.interop.xmodem_peers import pty_pair


def _data(n: int) -> bytes:
    return random.Random(n).randbytes(n).rstrip(b"\x1a")


class Worker(threading.Thread):
    """Run ``func`` in a thread and keep its result or exception."""

    def __init__(self, func: Callable[[], object]) -> None:
        super().__init__(daemon=True)
        self.func = func
        self.result: object = None
        self.error: BaseException | None = None

    def run(self) -> None:
        try:
            self.result = self.func()
        except BaseException as exc:  # handed to the test thread
            self.error = exc

    def outcome(self, timeout: float = 30.0) -> object:
        self.join(timeout)
        assert not self.is_alive(), "peer thread hung"
        if self.error is not None:
            raise self.error
        return self.result


@pytest.mark.parametrize("mode", list(Mode))
def test_blocking_send_to_receive_over_pty(mode: Mode) -> None:
    data = _data(50_000)
    with pty_pair() as pair:
        sink = io.BytesIO()
        # open our port first: opening a port discards input already waiting in it
        stream = SerialStream(pair.slave_path, 115200, timeout=0.05)
        peer = Worker(lambda: receive(FdStream(pair.master_fd, timeout=0.05), sink, mode=mode))
        peer.start()
        progress: list[tuple[int, int | None]] = []
        try:
            done = send(stream, data, mode=mode, progress=lambda a, b: progress.append((a, b)))
        finally:
            stream.close()
        received = peer.outcome()
    assert sink.getvalue() == data
    assert isinstance(received, Completed)
    assert done.size == len(data)
    assert progress[-1] == (len(data), len(data))


def test_blocking_receive_reports_a_cancel_as_typed_error() -> None:
    with pty_pair() as pair:
        master = FdStream(pair.master_fd, timeout=10.0)  # a read returns as data comes: the
        # timeout only bounds a wait for a receiver slowed by a busy machine

        def cancelling_sender() -> None:
            assert master.read(10) == b"C"
            master.write(b"\x18\x18\x18")

        peer = Worker(cancelling_sender)
        peer.start()
        stream = SerialStream(pair.slave_path, 115200, timeout=0.05)
        try:
            with pytest.raises(TransferError, match="sender cancelled"):
                receive(stream, io.BytesIO(), mode=Mode.CRC)
        finally:
            stream.close()
        peer.outcome()


def test_blocking_receive_times_out_when_nobody_sends() -> None:
    with pty_pair() as pair:
        stream = SerialStream(pair.slave_path, 115200, timeout=0.05)
        config = ReceiverConfig(start_timeout=0.3, start_interval=0.1)
        try:
            with pytest.raises(DncError, match=r"no XModem sender started within 0\.3 s"):
                receive(stream, io.BytesIO(), mode=Mode.CHECKSUM, config=config)
        finally:
            stream.close()


@pytest.mark.parametrize("mode", [Mode.CHECKSUM, Mode.ONE_K])
def test_asyncio_drivers_over_loopback_tcp(mode: Mode) -> None:
    data = _data(20_000)

    async def main() -> bytes:
        sink = io.BytesIO()
        done = asyncio.Event()

        async def serve(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
            try:
                await receive_async(reader, writer, sink, mode=mode)
            finally:
                writer.close()
                done.set()

        server = await asyncio.start_server(serve, "127.0.0.1", 0)
        port = server.sockets[0].getsockname()[1]
        reader, writer = await asyncio.open_connection("127.0.0.1", port)
        result = await asyncio.wait_for(send_async(reader, writer, data, mode=mode), 20)
        assert result.size == len(data)
        await asyncio.wait_for(done.wait(), 10)
        writer.close()
        server.close()
        await server.wait_closed()
        return sink.getvalue()

    assert asyncio.run(main()) == data


def test_asyncio_receive_sees_peer_close_as_typed_error() -> None:
    async def main() -> None:
        async def serve(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
            await reader.read(1)
            writer.close()

        server = await asyncio.start_server(serve, "127.0.0.1", 0)
        port = server.sockets[0].getsockname()[1]
        reader, writer = await asyncio.open_connection("127.0.0.1", port)
        with pytest.raises(PeerClosed):
            await asyncio.wait_for(receive_async(reader, writer, io.BytesIO()), 10)
        writer.close()
        server.close()
        await server.wait_closed()

    asyncio.run(main())


def test_final_events_come_before_the_last_bytes() -> None:
    """The Haas simulator relies on seeing Completed before the EOT's ACK is written."""
    from opendnc.xmodem.driver import run_blocking
    from opendnc.xmodem.framing import encode_block
    from opendnc.xmodem.receiver import XmodemReceiver

    log: list[object] = []
    incoming = [encode_block(1, b"abc", crc=False), encode_block(2, b"def", crc=False), b"\x04"]

    class Scripted:
        def read(self, max_bytes: int) -> bytes:
            if incoming:
                return incoming.pop(0)
            from opendnc.errors import TransportTimeout

            raise TransportTimeout("quiet")

        def write(self, data: bytes) -> None:
            log.append(data)

        def set_timeout(self, seconds: float | None) -> None:
            pass

        def close(self) -> None:
            pass

    engine = XmodemReceiver(Mode.CHECKSUM)
    run_blocking(engine, Scripted(), on_event=lambda e: log.append(type(e).__name__), poll=0.01)
    assert log[-2:] == ["Completed", b"\x06"]
    acks = [i for i, entry in enumerate(log) if entry == b"\x06"]
    # block 2 releases block 1's data: mid-transfer the ACK is written before that event
    assert acks[1] < log.index("DataReceived")
