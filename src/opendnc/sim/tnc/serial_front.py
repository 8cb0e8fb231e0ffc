"""The virtual TNC on an RS-232 line: serial LSV2 in front of the same sessions as TCP.

:class:`SerialFront` opens a serial device (a cable end, a pty slave) or creates a pty of its
own (``"pty"``), runs the control end of :class:`~opendnc.lsv2.serial_link.SerialLink` on the
server's event loop and hands every telegram received intact to an ordinary LSV2 session of
the server, exactly as if it had come over TCP; the session's answers go back as serial
transmissions. Files, machine parameters and PLC state are the server's: TCP clients and the
serial line see one control.

A serial line has no connections. The session (logins, buffer size) lasts until the client
logs out of everything (``A_LO`` without a name, what every client sends when it closes);
the telegram after that starts a fresh session with a 256-byte buffer, as after power-up.

POSIX only (non-blocking file descriptors on the event loop), like every pty simulator.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
from collections.abc import Callable
from typing import Any

from opendnc.errors import InputError, TransportError
from opendnc.heidenhain.blockwise import BlockwiseSettings
from opendnc.lsv2.framing import Frame, TelegramFramer
from opendnc.lsv2.serial_link import (
    DEFAULT_TIMING,
    LinkFailed,
    LinkRole,
    LinkTiming,
    SerialLink,
    TelegramReceived,
    describe_link_bytes,
)
from opendnc.lsv2.serial_stream import line_parity
from opendnc.sim.tnc.blockwise_front import BlockwiseService
from opendnc.sim.tnc.server import TncHandle, TncServer, _LinkProtocol
from opendnc.transport.marks import MarkDecoder, enable_marks
from opendnc.transport.pty import PtyPair, open_pty

__all__ = ["SerialFront"]

READ_CHUNK = 4096


class _SerialTransport(asyncio.Transport):
    """What an LSV2 session writes its TCP-framed answers into."""

    def __init__(self, front: SerialFront) -> None:
        super().__init__()
        self._front = front
        self._closing = False

    def write(self, data: bytes | bytearray | memoryview) -> None:
        if not self._closing:
            self._front._session_wrote(bytes(data))

    def is_closing(self) -> bool:
        return self._closing

    def close(self) -> None:
        if not self._closing:
            self._closing = True
            self._front._session_closed(self)

    def get_extra_info(self, name: str, default: Any = None) -> Any:
        return self._front.path if name == "peername" else default

    def pause_reading(self) -> None:
        pass  # the line is half-duplex: one telegram at a time, nothing piles up

    def resume_reading(self) -> None:
        pass


class SerialFront:
    """Serial LSV2 front-end of a running :class:`~opendnc.sim.tnc.server.TncServer`."""

    def __init__(
        self,
        server: TncServer,
        path: str,
        *,
        baud: int = 57600,
        parity: str = "E",
        bytesize: int = 8,
        stopbits: float = 1,
        timing: LinkTiming = DEFAULT_TIMING,
        retries: int = 3,
        trace_link: Callable[[str], None] | None = None,
        mode: str = "lsv2",
        mark_errors: bool = True,
    ) -> None:
        self.server = server
        self.requested = path
        self.path = path
        """The device served; for ``"pty"`` the slave path clients open."""
        self.baud, self.parity, self.bytesize, self.stopbits = baud, parity, bytesize, stopbits
        self.trace_link = trace_link
        self.link = SerialLink(
            LinkRole.CONTROL, timing=timing, retries=retries, on_bytes=self._on_link_bytes
        )
        if mode not in ("lsv2", "blockwise"):
            raise InputError(f"unknown serial mode {mode!r}: use lsv2 or blockwise")
        self.mode = mode
        self.blockwise: BlockwiseService | None = None
        if mode == "blockwise":
            self.blockwise = BlockwiseService(
                server.control.root / "TNC", note=trace_link, settings=BlockwiseSettings()
            )
        self.mark_errors = mark_errors
        """Have the device mark characters failing their parity check (docs/lsv2-serial.md,
        "Parity errors"), as a control's UART reports them; no effect on an own pty."""
        self._marks: MarkDecoder | None = None
        self._framer = TelegramFramer()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._fd = -1
        self._port: Any = None
        self._pty: PtyPair | None = None
        self._out = bytearray()
        self._writing = False
        self._timer: asyncio.TimerHandle | None = None
        self._proto: _LinkProtocol | None = None
        self._transport: _SerialTransport | None = None

    # -- life cycle ----------------------------------------------------------------------------

    async def start(self) -> None:
        """Open the line and start serving."""
        loop = asyncio.get_running_loop()
        self._loop = loop
        if self.requested == "pty":
            self._pty = open_pty()
            self._fd = self._pty.master_fd
            self.path = self._pty.slave_path
        else:
            from opendnc.transport.serial import open_serial

            self._port = open_serial(
                self.requested,
                self.baud,
                parity=line_parity(self.requested, self.parity),
                # a pty has no 7-bit mode either (see line_parity)
                bytesize=8 if line_parity(self.requested, "E") == "N" else self.bytesize,
                stopbits=self.stopbits,
                timeout=0,
            )
            self._fd = self._port.fileno()
            if self.mark_errors and enable_marks(self._port):
                self._marks = MarkDecoder()
        os.set_blocking(self._fd, False)
        loop.add_reader(self._fd, self._readable)
        self._new_session()

    async def close(self) -> None:
        """Stop serving and release the line."""
        if self._loop is not None and self._fd >= 0:
            self._loop.remove_reader(self._fd)
            if self._writing:
                self._loop.remove_writer(self._fd)
        if self._timer is not None:
            self._timer.cancel()
        self._end_session()
        if self._pty is not None:
            self._pty.close()
        elif self._port is not None:
            with contextlib.suppress(Exception):
                self._port.close()
        self._fd = -1

    # -- sessions ------------------------------------------------------------------------------

    def _new_session(self) -> None:
        transport = _SerialTransport(self)
        proto = _LinkProtocol(self.server)
        self._proto, self._transport = proto, transport
        proto.connection_made(transport)

    def _end_session(self) -> None:
        transport, self._transport = self._transport, None
        proto, self._proto = self._proto, None
        if transport is not None and proto is not None:
            transport._closing = True
            proto.connection_lost(None)

    def _session_closed(self, transport: _SerialTransport) -> None:
        # The session dropped itself (idle timeout, bad bytes): the line stays, a new one waits.
        if transport is self._transport:
            self._end_session()
            self._new_session()

    def _session_wrote(self, wire: bytes) -> None:
        self._framer.feed(wire)
        loop = self._loop
        assert loop is not None
        while (frame := self._framer.next_frame()) is not None:
            self.link.send(frame, loop.time())
        self._pump()

    # -- the line ------------------------------------------------------------------------------

    def _on_link_bytes(self, direction: str, data: bytes) -> None:
        if self.trace_link is not None:
            arrow = "<-" if direction == "recv" else "->"
            self.trace_link(f"{self.path} {arrow} {describe_link_bytes(data)}")

    def _readable(self) -> None:
        try:
            data = os.read(self._fd, READ_CHUNK)
        except BlockingIOError:
            return
        except OSError:
            # A pty whose slave is closed reports EIO until someone opens it again.
            data = b""
        if not data:
            return
        errors: tuple[int, ...] = ()
        if self._marks is not None:
            got = self._marks.decode(data)
            data, errors = got.data, got.errors
            if errors and self.trace_link is not None:
                self.trace_link(f"{self.path} <- {len(errors)} character(s) failed parity")
        loop = self._loop
        assert loop is not None
        if self.blockwise is not None:
            if self.trace_link is not None:
                self.trace_link(f"{self.path} <- {describe_link_bytes(data)}")
            self.blockwise.receive_data(data, loop.time(), errors)
        else:
            self.link.receive_data(data, loop.time(), errors)
        self._pump()

    def _tick(self) -> None:
        self._timer = None
        loop = self._loop
        assert loop is not None
        if self.blockwise is not None:
            self.blockwise.tick(loop.time())
        else:
            self.link.tick(loop.time())
        self._pump()

    def _pump(self) -> None:
        loop = self._loop
        assert loop is not None
        if self.blockwise is not None:
            out = self.blockwise.data_to_send()
            if out:
                if self.trace_link is not None:
                    self.trace_link(f"{self.path} -> {describe_link_bytes(out)}")
                self._write(out)
            self._arm(self.blockwise.deadline)
            return
        link = self.link
        while True:
            out = link.data_to_send()
            if out:
                self._write(out)
            event = link.next_event()
            if event is None:
                break
            if isinstance(event, TelegramReceived):
                self._deliver(event.frame)
            elif isinstance(event, LinkFailed) and self.server.trace:
                self.server.trace.note(self.path, str(event.error))
        self._arm(link.deadline)

    def _arm(self, deadline: float | None) -> None:
        loop = self._loop
        assert loop is not None
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        if deadline is not None:
            self._timer = loop.call_at(deadline, self._tick)

    def _deliver(self, frame: Frame) -> None:
        if self._proto is None:
            self._new_session()
        proto = self._proto
        assert proto is not None
        proto.data_received(TelegramFramer.encode(frame))
        if frame.mnemonic == "A_LO" and not frame.payload:
            # Logged out of everything: the answer is already queued on the line; whatever
            # comes next belongs to a new session (a new client on the same line).
            self._end_session()
            self._new_session()

    def _write(self, data: bytes) -> None:
        self._out += data
        self._flush()

    def _flush(self) -> None:
        loop = self._loop
        assert loop is not None
        while self._out:
            try:
                n = os.write(self._fd, self._out)
            except BlockingIOError:
                break
            except OSError as exc:
                raise TransportError(f"write to {self.path} failed: {exc}") from exc
            del self._out[:n]
        if self._out and not self._writing:
            self._writing = True
            loop.add_writer(self._fd, self._writable)
        elif not self._out and self._writing:
            self._writing = False
            loop.remove_writer(self._fd)

    def _writable(self) -> None:
        self._flush()


async def serve_serial(server: TncServer, path: str, **options: Any) -> SerialFront:
    """Start a :class:`SerialFront` for ``server`` on ``path`` (``"pty"``: a new pty)."""
    front = SerialFront(server, path, **options)
    await front.start()
    return front


def attach_serial(handle: TncHandle, path: str, **options: Any) -> SerialFront:
    """Serve the thread-hosted virtual TNC ``handle`` on a serial line too (blocking code).

    The front closes with the handle's loop; call ``detach_serial`` to stop it earlier.
    """
    future = asyncio.run_coroutine_threadsafe(
        serve_serial(handle.server, path, **options), handle._loop
    )
    return future.result(10)


def detach_serial(handle: TncHandle, front: SerialFront) -> None:
    """Stop a front started by :func:`attach_serial`."""
    asyncio.run_coroutine_threadsafe(front.close(), handle._loop).result(10)
