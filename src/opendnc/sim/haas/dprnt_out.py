"""DPRNT outputs of the virtual Haas: a TCP port (NGC Settings 261 = 2, 263), a file, and
a byte-writer adapter for a serial front-end.

All implement :class:`~opendnc.sim.haas.control.DprntOutput`.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Callable
from pathlib import Path

TCP_EOL = b"\r\n"
"""Line end on the TCP port and in the file (NGC; Haas documents CR for serial)."""

SESSION_END_TIMEOUT = 2.0  # seconds close() waits for its connection handlers to end


class TcpDprntOutput:
    """The control listens on a port; one reader connects and receives printed lines.

    Haas NGC accepts one reader connection (observed), so a second one is closed at once.
    Lines printed while nobody listens are counted in :attr:`dropped`, as a control does
    not buffer them.
    """

    def __init__(self, host: str = "127.0.0.1", port: int = 0, *, max_readers: int = 1) -> None:
        self.host, self.port = host, port
        self.max_readers = max_readers
        self.readers: list[asyncio.StreamWriter] = []
        self.sent = 0
        self.dropped = 0
        self._server: asyncio.Server | None = None
        # the connection handlers still running: close() lets them end before it returns, or
        # a stop would cancel them mid-read and Python 3.11 logs that as a traceback
        self._sessions: set[asyncio.Task[None]] = set()
        self._connected = asyncio.Event()

    async def start(self) -> int:
        """Start listening; returns the bound port."""
        self._server = await asyncio.start_server(self._session, self.host, self.port)
        self.port = self._server.sockets[0].getsockname()[1]
        return self.port

    async def wait_reader(self, timeout: float) -> bool:
        """Wait until a reader is connected (True) or ``timeout`` passes (False)."""
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(self._connected.wait(), timeout)
        return bool(self.readers)

    async def close(self) -> None:
        """Stop listening and close readers."""
        if self._server is not None:
            self._server.close()
        for writer in list(self.readers):
            writer.close()
        if self._sessions:
            await asyncio.wait(list(self._sessions), timeout=SESSION_END_TIMEOUT)
        if self._server is not None:
            with contextlib.suppress(OSError):
                await self._server.wait_closed()

    async def _session(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        if task is not None:
            self._sessions.add(task)
            task.add_done_callback(self._sessions.discard)
        if len(self.readers) >= self.max_readers:
            writer.close()
            return
        self.readers.append(writer)
        self._connected.set()
        try:
            # The reader only reads; wait for it to hang up and ignore anything it sends.
            while await reader.read(1024):
                pass
        except OSError:
            pass
        finally:
            self._forget(writer)

    def _forget(self, writer: asyncio.StreamWriter) -> None:
        if writer in self.readers:
            self.readers.remove(writer)
        if not self.readers:
            self._connected.clear()
        writer.close()

    def write_line(self, text: str) -> None:
        """Send one line to the connected reader(s)."""
        if not self.readers:
            self.dropped += 1
            return
        data = text.encode("latin-1", "replace") + TCP_EOL
        for writer in list(self.readers):
            if writer.is_closing():
                self._forget(writer)
                continue
            writer.write(data)
        self.sent += 1

    def write_control(self, code: bytes) -> None:
        """POPEN/PCLOS bytes are not sent over TCP."""


class FileDprntOutput:
    """Append each printed line to a file (NGC Setting 261 = 1, path in Setting 262)."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.sent = 0

    def write_line(self, text: str) -> None:
        """Append ``text`` and a line end; flushed at once so readers never miss a line."""
        with self.path.open("ab") as handle:
            handle.write(text.encode("latin-1", "replace") + TCP_EOL)
        self.sent += 1

    def write_control(self, code: bytes) -> None:
        """POPEN/PCLOS bytes are not written to the file."""


class StreamDprntOutput:
    """DPRNT as a serial port carries it: each line then CR, DC2/DC4 for POPEN/PCLOS.

    ``write`` takes the bytes (a serial front-end passes its port's writer). Haas documents a
    carriage return after every DPRNT block; ``eol`` may follow Setting 25 instead.
    """

    def __init__(self, write: Callable[[bytes], None], eol: bytes = b"\r") -> None:
        self._write = write
        self.eol = eol
        self.sent = 0

    def write_line(self, text: str) -> None:
        """Send ``text`` and the line end."""
        self._write(text.encode("latin-1", "replace") + self.eol)
        self.sent += 1

    def write_control(self, code: bytes) -> None:
        """Send the POPEN (DC2) / PCLOS (DC4) byte."""
        self._write(code)
