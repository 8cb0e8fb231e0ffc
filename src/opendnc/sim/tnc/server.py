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
import os
import shutil
import tempfile
import threading
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar, cast

from opendnc.errors import LocalProtocolError, RemoteProtocolError, TransportError
from opendnc.lsv2.connection import Lsv2Connection, Role, UndecodableTelegram
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
#: Pipelined telegrams answered in one go before other connections get a turn.
BURST = 32
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
        self._links: set[_LinkProtocol] = set()
        self._timers: set[asyncio.TimerHandle] = set()
        self.host = ""
        self.port = 0

    async def start(self, host: str = "127.0.0.1", port: int = 0) -> None:
        """Listen on ``host:port`` (port 0: any free port, read back into ``.port``)."""
        loop = asyncio.get_running_loop()
        self._server = await loop.create_server(lambda: _LinkProtocol(self), host, port)
        sock = self._server.sockets[0].getsockname()
        self.host, self.port = sock[0], sock[1]

    async def close(self) -> None:
        """Stop listening and drop every connection."""
        if self._server is not None:
            self._server.close()
        for timer in self._timers:
            timer.cancel()
        self._timers.clear()
        for link in list(self._links):
            link.drop()
        await asyncio.sleep(0)  # let the transports report connection_lost
        if self._server is not None:
            with contextlib.suppress(asyncio.TimeoutError):
                await asyncio.wait_for(self._server.wait_closed(), 2)
        self.control.save_state()

    async def serve_forever(self) -> None:
        """Run until cancelled."""
        assert self._server is not None
        await self._server.serve_forever()

    def later(self, when: float, fn: Callable[..., None], *args: object) -> None:
        """Run ``fn(*args)`` at loop time ``when``, unless the server closes first."""
        timer: asyncio.TimerHandle | None = None

        def run() -> None:
            self._timers.discard(timer)
            fn(*args)

        timer = asyncio.get_running_loop().call_at(when, run)
        self._timers.add(timer)


class _LinkProtocol(asyncio.Protocol):
    """One client connection, served straight from the event loop's callbacks.

    Requests are answered inside ``data_received`` without a task, a future or an ``await``
    per telegram: at thousands of telegrams per second (4 KiB file blocks on loopback) the
    coroutine machinery of ``StreamReader``/``StreamWriter`` was most of the simulator's
    cost. Fairness and back-pressure are kept by pausing the transport's reading: after
    :data:`BURST` pipelined telegrams (others get a turn) and while the client does not
    read its answers (``pause_writing``).
    """

    def __init__(self, server: TncServer) -> None:
        self.server = server
        self.link = Lsv2Connection(Role.SERVER, max_payload=MAX_WIRE_PAYLOAD)
        self.session = Session(server.control, self.link)
        self.transport: asyncio.Transport | None = None
        self.peer = ""
        self._loop = asyncio.get_running_loop()
        self._gone = False
        self._write_paused = False
        self._yielding = False
        self._reading_paused = False
        self._last = self._loop.time()
        self._idle: asyncio.TimerHandle | None = None
        self._send_at = 0.0

    # -- transport callbacks -----------------------------------------------------------------
    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        # A stream transport (uvloop's does not subclass asyncio.Transport, hence no isinstance).
        self.transport = cast(asyncio.Transport, transport)
        self.peer = str(transport.get_extra_info("peername"))
        server = self.server
        server._links.add(self)
        server.connections += 1
        if server.connections > server.max_connections:
            # Like a control out of LSV2 handles: error 80, then hang up.
            self._send([Refused(E.T_ER_TO_MANY_OPEN_TCP)])
            self.drop()
            return
        self._idle = self._loop.call_later(server.idle_timeout, self._check_idle)

    def data_received(self, data: bytes) -> None:
        self._last = self._loop.time()
        self.link.receive_data(data)
        self._process()

    def eof_received(self) -> bool:
        return False  # the client hung up: close our side too

    def connection_lost(self, exc: Exception | None) -> None:
        if self._gone:
            return
        self._gone = True
        self.server.connections -= 1
        self.server._links.discard(self)
        self.session.close()  # drops a partial upload
        if self._idle is not None:
            self._idle.cancel()

    def pause_writing(self) -> None:
        self._write_paused = True
        self._update_reading()

    def resume_writing(self) -> None:
        self._write_paused = False
        self._update_reading()
        self._process()

    # -- serving -----------------------------------------------------------------------------
    def drop(self) -> None:
        """Close this connection (answers already written are still delivered)."""
        if self.transport is not None and not self.transport.is_closing():
            self.transport.close()
        self.connection_lost(None)

    def _update_reading(self) -> None:
        transport = self.transport
        if transport is None or transport.is_closing():
            return
        paused = self._write_paused or self._yielding
        if paused != self._reading_paused:
            self._reading_paused = paused
            if paused:
                transport.pause_reading()
            else:
                transport.resume_reading()

    def _resume_after_yield(self) -> None:
        self._yielding = False
        self._update_reading()
        self._process()

    def _check_idle(self) -> None:
        quiet = self._loop.time() - self._last
        if quiet >= self.server.idle_timeout:
            self.drop()
        else:
            self._idle = self._loop.call_later(self.server.idle_timeout - quiet, self._check_idle)

    def _process(self) -> None:
        """Answer every complete telegram received so far (up to :data:`BURST`)."""
        try:
            self._answer_all()
        except Exception:
            # A bug must cost one connection, never the server or the other clients.
            _log.exception("virtual TNC: dropping connection %s after an internal error", self.peer)
            self.drop()

    def _answer_all(self) -> None:
        link, session, trace = self.link, self.session, self.server.trace
        handled = 0
        while not self._gone and not self._write_paused and not self._yielding:
            if handled == BURST:
                # A client pipelining many telegrams must not starve the others.
                self._yielding = True
                self._update_reading()
                self._loop.call_soon(self._resume_after_yield)
                return
            handled += 1
            try:
                request = link.next_event()
            except UndecodableTelegram as exc:
                # A whole telegram arrived but does not decode: refuse it, carry on.
                if trace:
                    trace.raw(self.peer, "<-", exc.frame, str(exc))
                known = exc.frame.mnemonic in REGISTRY
                self._send([Refused(E.T_ER_BAD_FORMAT if known else E.T_ER_UNKNOWN_TELE)])
                continue
            except RemoteProtocolError as exc:
                # The framer lost sync (bad name, absurd length): answer, hang up.
                if trace:
                    trace.note(self.peer, f"dropping connection: {exc}")
                self._send([Refused(E.T_ER_BAD_FORMAT)])
                self.drop()
                return
            if request is None:
                return
            frame = link.last_frame
            assert frame is not None
            if trace:
                trace.raw(self.peer, "<-", frame, repr(request))
            result = session.handle(request, HEADER_SIZE + len(frame.payload))
            self._send(result.frames)
            for deferred in result.deferred:
                self.server.later(self._loop.time() + deferred.delay, self._fire, deferred)

    def _fire(self, deferred: Deferred) -> None:
        message = deferred.make()  # runs even if the client left (e.g. writes the log file)
        if message is not None:
            self._send([message])

    def _send(self, messages: list[Message]) -> None:
        transport = self.transport
        if transport is None or transport.is_closing():
            return
        for message in messages:
            try:
                wire = self.link.send(message)
            except LocalProtocolError:
                # An answer that does not fit the client's buffer: refuse instead.
                wire = self.link.send(Refused(E.T_ER_WRONG_PARA))
            if self.server.trace:
                self.server.trace.wire(self.peer, "->", wire, repr(message))
            if self.server.latency:
                self._write_later(wire)
            else:
                # One write per telegram: pyLSV2 expects the header in its first recv().
                transport.write(wire)

    def _write_later(self, wire: bytes) -> None:
        # Each telegram leaves ``latency`` seconds after the previous one, in order.
        now = self._loop.time()
        self._send_at = max(now, self._send_at) + self.server.latency
        self.server.later(self._send_at, self._write_now, wire)

    def _write_now(self, wire: bytes) -> None:
        if self.transport is not None and not self.transport.is_closing():
            self.transport.write(wire)


def new_event_loop() -> asyncio.AbstractEventLoop:
    """The event loop the simulator runs on: uvloop when installed (``opendnc[sim]``), else
    asyncio's own.

    Per 4 KiB file block the server does one poll, one recv and one send; on the standard
    loop the Python code around those syscalls costs about as much as the whole LSV2
    session logic. ``OPENDNC_SIM_LOOP=asyncio`` forces the standard loop (to compare).
    """
    if os.environ.get("OPENDNC_SIM_LOOP", "").lower() != "asyncio":
        try:
            import uvloop
        except ImportError:
            pass  # optional extra not installed: the standard loop serves just as well
        else:
            return uvloop.new_event_loop()
    return asyncio.new_event_loop()


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
    listen: bool = True,
) -> TncServer:
    """Start a virtual TNC inside the running event loop and return the listening server
    (``listen=False``: no TCP port, for a control reached only over a serial front-end)."""
    prof = get_profile(profile)
    root_path = Path(root) if root is not None else default_root(prof.key)
    root_path.mkdir(parents=True, exist_ok=True)
    control = Control(prof, root_path, dnc_option=dnc_option)
    server = TncServer(control, latency=latency, trace=trace)
    if listen:
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
    loop = new_event_loop()
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
        raise TransportError("the virtual TNC did not start within 30 s")
    return TncHandle(ready[0], loop, thread, temp_root=root is None)
