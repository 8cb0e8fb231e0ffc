"""asyncio LSV2 server of the virtual TNC, plus a thread-hosted handle for blocking code.

Each connection gets a :class:`~opendnc.sim.tnc.session.Session` and the shared
:class:`~opendnc.sim.tnc.control.Control`; bytes go through the same sans-IO engine the
client uses (:class:`~opendnc.lsv2.connection.Lsv2Connection` in the server role: framing,
typed decoding, buffer size and secure-send bookkeeping).  A connection that sends
bytes which cannot be framed, or vanishes, is dropped alone (its partial upload is deleted);
the server and every other connection carry on.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import shutil
import tempfile
import threading
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

from opendnc.errors import LocalProtocolError, RemoteProtocolError
from opendnc.lsv2.connection import Lsv2Connection, Role
from opendnc.lsv2.constants import ErrorCode as E
from opendnc.lsv2.framing import HEADER_SIZE
from opendnc.lsv2.messages import REGISTRY, Message, Refused

# Importing the handler modules registers their telegrams.
from opendnc.sim.tnc import handlers_files, handlers_machine, handlers_session
from opendnc.sim.tnc.control import Control
from opendnc.sim.tnc.profiles import get_profile
from opendnc.sim.tnc.session import Deferred, Session
from opendnc.sim.tnc.trace import TraceHook

_log = logging.getLogger(__name__)
_HANDLER_MODULES = (handlers_files, handlers_machine, handlers_session)
T = TypeVar("T")

#: Largest telegram payload accepted at all; longer announcements drop the connection.
MAX_WIRE_PAYLOAD = 65536
IDLE_TIMEOUT = 600.0
#: Connections served at once; beyond it a newcomer gets T_ER 80 and is closed.
MAX_CONNECTIONS = 256


class TncServer:
    """A running virtual TNC bound to a TCP port (asyncio)."""

    def __init__(
        self,
        control: Control,
        *,
        latency: float = 0.0,
        trace: TraceHook | None = None,
        idle_timeout: float = IDLE_TIMEOUT,
        max_connections: int = MAX_CONNECTIONS,
    ) -> None:
        self.control = control
        self.max_connections = max_connections
        self.connections = 0
        self.latency = latency
        self.trace = trace
        self.idle_timeout = idle_timeout
        self._server: asyncio.Server | None = None
        self._tasks: set[asyncio.Task[None]] = set()
        self.host = ""
        self.port = 0

    async def start(self, host: str = "127.0.0.1", port: int = 0) -> None:
        """Listen on ``host:port`` (port 0: any free port, read back into ``.port``)."""
        self._server = await asyncio.start_server(self._connection, host, port, limit=2**17)
        sock = self._server.sockets[0].getsockname()
        self.host, self.port = sock[0], sock[1]

    async def close(self) -> None:
        """Stop listening and drop every connection."""
        if self._server is not None:
            self._server.close()
        for task in list(self._tasks):
            task.cancel()
        if self._tasks:
            await asyncio.gather(*self._tasks, return_exceptions=True)
        if self._server is not None:
            with contextlib.suppress(asyncio.TimeoutError):
                await asyncio.wait_for(self._server.wait_closed(), 2)
        self.control.save_state()

    async def serve_forever(self) -> None:
        """Run until cancelled."""
        assert self._server is not None
        await self._server.serve_forever()

    async def _connection(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        self._tasks.add(task)
        link = Lsv2Connection(Role.SERVER, max_payload=MAX_WIRE_PAYLOAD)
        session = Session(self.control, link)
        peer = str(writer.get_extra_info("peername"))
        lock = asyncio.Lock()
        self.connections += 1
        try:
            if self.connections > self.max_connections:
                # Like a control out of LSV2 handles: error 80, then hang up.
                await self._send(link, writer, lock, [Refused(E.T_ER_TO_MANY_OPEN_TCP)], peer)
                return
            await self._serve(session, link, reader, writer, lock, peer)
        except (ConnectionError, asyncio.IncompleteReadError, TimeoutError):
            pass  # peer vanished: only this connection ends
        except asyncio.CancelledError:
            pass  # server shutting down; the connection is closed below
        except Exception:
            # A bug must cost one connection, never the server or the other clients.
            _log.exception("virtual TNC: dropping connection %s after an internal error", peer)
        finally:
            self.connections -= 1
            session.close()
            self._tasks.discard(task)
            writer.close()
            with contextlib.suppress(ConnectionError, OSError):
                await writer.wait_closed()

    async def _serve(
        self,
        session: Session,
        link: Lsv2Connection,
        reader: asyncio.StreamReader,
        writer: asyncio.StreamWriter,
        lock: asyncio.Lock,
        peer: str,
    ) -> None:
        while True:
            data = await asyncio.wait_for(reader.read(65536), self.idle_timeout)
            if not data:
                return
            link.receive_data(data)
            handled = 0
            while True:
                handled += 1
                if handled % 32 == 0:
                    # A client pipelining many telegrams must not starve the others.
                    await asyncio.sleep(0)
                before = link.last_frame
                try:
                    request = link.next_event()
                except RemoteProtocolError as exc:
                    frame = link.last_frame
                    if frame is None or frame is before:
                        # The framer lost sync (bad name, absurd length): answer, hang up.
                        if self.trace:
                            self.trace.note(peer, f"dropping connection: {exc}")
                        await self._send(link, writer, lock, [Refused(E.T_ER_BAD_FORMAT)], peer)
                        return
                    # A whole telegram arrived but does not decode: refuse it, carry on.
                    if self.trace:
                        self.trace.raw(peer, "<-", frame, str(exc))
                    known = frame.mnemonic in REGISTRY
                    code = E.T_ER_BAD_FORMAT if known else E.T_ER_UNKNOWN_TELE
                    await self._send(link, writer, lock, [Refused(code)], peer)
                    continue
                if request is None:
                    break
                frame = link.last_frame
                assert frame is not None
                if self.trace:
                    self.trace.raw(peer, "<-", frame, repr(request))
                result = session.handle(request, HEADER_SIZE + len(frame.payload))
                await self._send(link, writer, lock, result.frames, peer)
                for deferred in result.deferred:
                    self._spawn_deferred(deferred, link, writer, lock, peer)

    async def _send(
        self,
        link: Lsv2Connection,
        writer: asyncio.StreamWriter,
        lock: asyncio.Lock,
        messages: list[Message],
        peer: str,
    ) -> None:
        async with lock:
            for message in messages:
                if self.latency:
                    await asyncio.sleep(self.latency)
                try:
                    wire = link.send(message)
                except LocalProtocolError:
                    # An answer that does not fit the client's buffer: refuse instead.
                    wire = link.send(Refused(E.T_ER_WRONG_PARA))
                if self.trace:
                    self.trace.wire(peer, "->", wire, repr(message))
                # One write per telegram: pyLSV2 expects the header in its first recv().
                writer.write(wire)
            await writer.drain()

    def _spawn_deferred(
        self,
        deferred: Deferred,
        link: Lsv2Connection,
        writer: asyncio.StreamWriter,
        lock: asyncio.Lock,
        peer: str,
    ) -> None:
        async def later() -> None:
            await asyncio.sleep(deferred.delay)
            message = deferred.make()
            if message is not None and not writer.is_closing():
                with contextlib.suppress(ConnectionError, OSError):
                    await self._send(link, writer, lock, [message], peer)

        task = asyncio.get_running_loop().create_task(later())
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)


def default_root(profile: str) -> Path:
    """A fresh folder for a programming station (used when no root is given)."""
    return Path(tempfile.mkdtemp(prefix=f"opendnc-{profile}-"))


async def serve_tnc(
    profile: str = "tnc640",
    root: Path | str | None = None,
    host: str = "127.0.0.1",
    port: int = 0,
    *,
    latency: float = 0.0,
    trace: TraceHook | None = None,
    dnc_option: bool = True,
) -> TncServer:
    """Start a virtual TNC inside the running event loop and return the listening server."""
    prof = get_profile(profile)
    root_path = Path(root) if root is not None else default_root(prof.key)
    root_path.mkdir(parents=True, exist_ok=True)
    control = Control(prof, root_path, dnc_option=dnc_option)
    server = TncServer(control, latency=latency, trace=trace)
    await server.start(host, port)
    return server


class TncHandle:
    """A virtual TNC running on its own event loop in a background thread.

    Use as a context manager; ``.host``/``.port`` tell where it listens, ``.root`` where its
    drives live, ``.call(fn)`` runs ``fn(control)`` on the simulator's thread (the model is not
    thread-safe), ``.stop()`` shuts it down.
    """

    def __init__(
        self,
        server: TncServer,
        loop: asyncio.AbstractEventLoop,
        thread: threading.Thread,
        temp_root: bool,
    ) -> None:
        self.server = server
        self._loop = loop
        self._thread = thread
        self._temp_root = temp_root
        self.control = server.control
        self.host = server.host
        self.port = server.port
        self.root = server.control.root
        self.profile = server.control.profile

    def call(self, fn: Callable[[Control], T]) -> T:
        """Run ``fn(control)`` on the simulator thread and return its result."""

        async def run() -> T:
            return fn(self.control)

        return asyncio.run_coroutine_threadsafe(run(), self._loop).result(10)

    def stop(self) -> None:
        """Stop the server and its thread (idempotent)."""
        if not self._thread.is_alive():
            return
        fut = asyncio.run_coroutine_threadsafe(self.server.close(), self._loop)
        with contextlib.suppress(TimeoutError):
            fut.result(10)
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(10)
        if self._temp_root:
            shutil.rmtree(self.root, ignore_errors=True)

    def __enter__(self) -> TncHandle:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


def start_tnc(
    profile: str = "tnc640",
    root: Path | str | None = None,
    host: str = "127.0.0.1",
    port: int = 0,
    *,
    latency: float = 0.0,
    trace: TraceHook | None = None,
    dnc_option: bool = True,
) -> TncHandle:
    """Start a virtual TNC in a background thread; returns once it listens.

    With ``root=None`` a temporary programming-station folder is created and removed by
    ``stop()``.
    """
    loop = asyncio.new_event_loop()
    ready: list[TncServer] = []
    failure: list[BaseException] = []
    started = threading.Event()

    def runner() -> None:
        asyncio.set_event_loop(loop)
        try:
            server = loop.run_until_complete(
                serve_tnc(
                    profile, root, host, port, latency=latency, trace=trace, dnc_option=dnc_option
                )
            )
            ready.append(server)
        except BaseException as exc:  # reported to the starting thread below
            failure.append(exc)
            started.set()
            return
        started.set()
        loop.run_forever()
        loop.close()

    thread = threading.Thread(target=runner, name=f"virtual-tnc-{profile}", daemon=True)
    thread.start()
    started.wait(30)
    if failure:
        raise failure[0]
    if not ready:
        raise RuntimeError("virtual TNC did not start")
    return TncHandle(ready[0], loop, thread, temp_root=root is None)
