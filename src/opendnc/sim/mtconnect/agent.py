"""A virtual MTConnect agent: HTTP on loopback, ``/probe``, ``/current`` and
``/sample?from=&count=&interval=&heartbeat=`` (and the same under ``/<device>/``), with
multipart streaming, a bounded buffer and an instance id that changes on :meth:`restart`
(docs/mtconnect-input.md#the-virtual-agent).

It behaves as the reference agent does where a client can tell: every value starts
UNAVAILABLE, an observation is stored only when its value changes, ``from`` outside the
buffer is ``OUT_OF_RANGE``, a quiet stream sends an empty document every heartbeat, and a
restart starts the sequence again at 1 with a new instance id and every value resent. Its
values come from :class:`~opendnc.sim.mtconnect.machine.ScriptedMachine` (or a test) through
:meth:`VirtualAgent.set`. It is served by uvicorn as a bare ASGI application (the ``server``
extra).
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
import uuid
from collections.abc import Awaitable, Callable, Iterator, MutableMapping
from datetime import UTC, datetime
from typing import Any
from urllib.parse import parse_qs

from opendnc.errors import InputError
from opendnc.sim.mtconnect.documents import (
    ITEMS,
    ItemDef,
    Stored,
    devices_xml,
    error_xml,
    streams_xml,
)

__all__ = ["VirtualAgent"]

Scope = MutableMapping[str, Any]
Message = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[Message]]
Send = Callable[[Message], Awaitable[None]]

_XML = b"text/xml; charset=utf-8"
_BY_TYPE = {item.type: item for item in ITEMS}


class VirtualAgent:
    """An agent for devices ``names`` on ``host:port`` (0: a free port, kept over restarts).

    ``streaming=False`` makes it refuse ``interval`` (UNSUPPORTED), as an agent behind a proxy
    that cuts long answers would be answered; the client then polls ``current``.
    """

    def __init__(
        self,
        names: list[str],
        *,
        host: str = "127.0.0.1",
        port: int = 0,
        buffer_size: int = 1024,
        streaming: bool = True,
        sender: str = "opendnc-sim",
    ) -> None:
        if not names or len(set(names)) != len(names):
            raise InputError("a virtual agent needs distinct device names")
        self.names = list(names)
        self.host = host
        self.port = port
        self.buffer_size = buffer_size
        self.streaming = streaming
        self.sender = sender
        self.instance = 1
        self.stalled = False  # streams send nothing while set (a slow link: tests make gaps)
        # a ring: sequence s sits at s % buffer_size while it is in the buffer (a sample reads
        # only what it sends, whatever the buffer's size)
        self._ring: list[Stored | None] = [None] * buffer_size
        self._latest: dict[tuple[int, str], Stored] = {}  # (device, item key) -> newest
        self._active: dict[int, dict[str, tuple[str, str]]] = {}  # conditions by native code
        self._next = 1
        self._changed = asyncio.Event()
        self._closing = False
        self._web: Any = None
        self._serving: asyncio.Task[None] | None = None
        self._boundary = uuid.uuid4().hex
        self.requests = 0  # requests answered (benchmarks)
        for index in range(len(names)):
            for item in ITEMS:
                if item.category == "CONDITION":
                    self._condition(index, item, "Unavailable", "", "")
                else:
                    self._store(index, item, "UNAVAILABLE")

    # -- values ----------------------------------------------------------------------------

    def device_index(self, name: str) -> int:
        """The index of device ``name``."""
        try:
            return self.names.index(name)
        except ValueError:
            raise InputError(f"the virtual agent has no device {name!r}") from None

    def set(self, device: str, item_type: str, value: str | int) -> None:
        """Set event ``item_type`` (``EXECUTION``, ``PART_COUNT``, ...) of ``device``; stored
        only when it changes, as an agent stores it."""
        index = self.device_index(device)
        item = _BY_TYPE[item_type]
        latest = self._latest.get((index, item.key))
        if latest is not None and latest.value == str(value):
            return
        self._store(index, item, str(value))
        self._notify()

    def fault(self, device: str, native_code: str, text: str, *, level: str = "Fault") -> None:
        """Raise a SYSTEM condition on ``device`` (a control's alarm)."""
        index = self.device_index(device)
        self._condition(index, _BY_TYPE["SYSTEM"], level, native_code, text)
        self._notify()

    def clear_faults(self, device: str) -> None:
        """Every SYSTEM condition of ``device`` back to Normal (a reset)."""
        index = self.device_index(device)
        self._condition(index, _BY_TYPE["SYSTEM"], "Normal", "", "")
        self._notify()

    def _condition(self, index: int, item: ItemDef, level: str, code: str, text: str) -> None:
        active = self._active.setdefault(index, {})
        if level in ("Normal", "Unavailable") and not code:
            active.clear()
        elif level == "Normal":
            active.pop(code, None)
        else:
            active[code] = (level, text)
        self._store(index, item, text, level=level, native_code=code)

    def _store(
        self, index: int, item: ItemDef, value: str, *, level: str = "", native_code: str = ""
    ) -> None:
        stored = Stored(self._next, index, item, datetime.now(UTC), value, level, native_code)
        self._next += 1
        self._ring[stored.sequence % self.buffer_size] = stored
        self._latest[(index, item.key)] = stored

    def _notify(self) -> None:
        self._changed.set()
        self._changed = asyncio.Event()

    @property
    def first_sequence(self) -> int:
        """The oldest sequence still in the buffer."""
        return max(1, self._next - self.buffer_size)

    def _current_observations(self, only: int | None) -> Iterator[Stored]:
        for (index, _key), stored in self._latest.items():
            if only is not None and index != only:
                continue
            active = self._active.get(index, {})
            if stored.item.category != "CONDITION" or not active:
                yield stored  # an event, or a condition that is Normal or Unavailable
                continue
            for code, (level, text) in active.items():  # every active entry, as an agent does
                yield Stored(
                    stored.sequence, index, stored.item, stored.timestamp, text, level, code
                )

    # -- serving ---------------------------------------------------------------------------

    @property
    def url(self) -> str:
        """The agent's base URL."""
        return f"http://{self.host}:{self.port}"

    async def start(self) -> None:
        """Listen (on a free port the first time when ``port`` is 0)."""
        try:
            import uvicorn
        except ImportError:
            raise InputError(
                "the virtual MTConnect agent needs opendnc[server] (uvicorn)"
            ) from None

        class Web(uvicorn.Server):
            # the process's signals belong to whoever runs the agent (the fleet, a test)
            @contextlib.contextmanager
            def capture_signals(self) -> Iterator[None]:
                yield

        listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        listener.bind((self.host, self.port))
        listener.listen(64)
        listener.setblocking(False)
        self.port = listener.getsockname()[1]
        config = uvicorn.Config(
            self._app,
            interface="asgi3",
            log_level="warning",
            lifespan="off",
            timeout_graceful_shutdown=1,
        )
        self._closing = False
        self._web = Web(config)
        self._serving = asyncio.create_task(self._web.serve(sockets=[listener]))
        while not self._web.started:
            if self._serving.done():
                await self._serving  # raises what stopped it
                raise InputError("the virtual agent stopped while starting")
            await asyncio.sleep(0.005)

    async def close(self) -> None:
        """Stop serving (open streams end)."""
        web, serving = self._web, self._serving
        if web is not None and serving is not None:
            web.should_exit = True
            # uvicorn stops listening at its next tick: streams end after that, or a client
            # would reconnect to the closing agent and be ended at once, again and again
            deadline = asyncio.get_running_loop().time() + 2
            while any(s.is_serving() for s in web.servers) and not serving.done():
                if asyncio.get_running_loop().time() > deadline:
                    break
                await asyncio.sleep(0.005)
        self._closing = True
        self._notify()
        if serving is not None:
            with contextlib.suppress(Exception):
                await serving
        self._web = self._serving = None

    async def restart(self) -> None:
        """Stop, then start again on the same port as a new instance: sequence from 1, every
        current value resent (an agent's adapters reconnect and send their state)."""
        await self.close()
        latest = sorted(self._latest.values(), key=lambda s: s.sequence)
        self.instance += 1
        self._ring = [None] * self.buffer_size
        self._latest.clear()
        self._next = 1
        for stored in latest:
            if stored.item.category == "CONDITION":
                continue
            self._store(stored.device, stored.item, stored.value)
        conditions = {s.device: s.item for s in latest if s.item.category == "CONDITION"}
        for index, item in conditions.items():
            active = dict(self._active.get(index, {}))
            self._condition(index, item, "Normal", "", "")
            for code, (level, text) in active.items():
                self._condition(index, item, level, code, text)
        await self.start()

    def _document(self, observations: list[Stored], next_sequence: int, only: int | None) -> bytes:
        return streams_xml(
            self.names,
            observations,
            instance=self.instance,
            sender=self.sender,
            buffer_size=self.buffer_size,
            first=self.first_sequence,
            last=self._next - 1,
            next_sequence=next_sequence,
            only=only,
        )

    def _error(self, code: str, text: str) -> bytes:
        return error_xml(
            code, text, instance=self.instance, sender=self.sender, buffer_size=self.buffer_size
        )

    def _chosen(self, start: int, count: int, only: int | None) -> tuple[list[Stored], int]:
        """Up to ``count`` observations from ``start`` (of device ``only``), and the next
        sequence to ask for."""
        end = min(self._next, start + count)
        chosen = []
        for sequence in range(start, end):
            stored = self._ring[sequence % self.buffer_size]
            if stored is not None and (only is None or stored.device == only):
                chosen.append(stored)
        return chosen, end

    def _sample(self, start: int, count: int, only: int | None) -> bytes:
        chosen, end = self._chosen(start, count, only)
        return self._document(chosen, end, only)

    async def _app(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            return
        self.requests += 1
        parts = [p for p in scope["path"].split("/") if p]
        query = {k: v[-1] for k, v in parse_qs(scope.get("query_string", b"").decode()).items()}
        only: int | None = None
        if len(parts) == 2:
            if parts[0] not in self.names:
                await _answer(send, 404, self._error("NO_DEVICE", f"no device {parts[0]!r}"))
                return
            only = self.names.index(parts[0])
            parts = parts[1:]
        request = parts[0] if parts else "probe"
        try:
            numbers = {
                k: int(query[k]) for k in ("from", "count", "interval", "heartbeat") if k in query
            }
        except ValueError:
            await _answer(send, 400, self._error("INVALID_PARAMETER_VALUE", "not a number"))
            return
        if request == "probe":
            body = devices_xml(
                self.names,
                instance=self.instance,
                sender=self.sender,
                buffer_size=self.buffer_size,
                only=only,
            )
            await _answer(send, 200, body)
        elif request == "current" and "interval" not in numbers:
            body = self._document(list(self._current_observations(only)), self._next, only)
            await _answer(send, 200, body)
        elif request in ("sample", "current"):
            if "interval" in numbers and not self.streaming:
                await _answer(send, 400, self._error("UNSUPPORTED", "streaming is off"))
                return
            start = numbers.get("from", self.first_sequence)
            if not self.first_sequence <= start <= self._next:
                text = f"'from' must be {self.first_sequence}..{self._next}"
                await _answer(send, 400, self._error("OUT_OF_RANGE", text))
                return
            count = numbers.get("count", 100)
            if "interval" not in numbers:
                await _answer(send, 200, self._sample(start, count, only))
                return
            heartbeat = numbers.get("heartbeat", 10000) / 1000
            await self._stream(
                send, receive, start, count, numbers["interval"] / 1000, heartbeat, only
            )
        else:
            await _answer(send, 400, self._error("UNSUPPORTED", f"no request {request!r}"))

    async def _stream(
        self,
        send: Send,
        receive: Receive,
        start: int,
        count: int,
        interval: float,
        heartbeat: float,
        only: int | None,
    ) -> None:
        """A multipart answer: a document whenever observations arrive (at most one per
        ``interval``), an empty one after ``heartbeat`` of quiet, until the client goes."""
        gone = asyncio.Event()

        async def watch() -> None:
            while (await receive())["type"] != "http.disconnect":
                pass
            gone.set()

        watcher = asyncio.create_task(watch())
        boundary = self._boundary.encode()
        await send(
            {
                "type": "http.response.start",
                "status": 200,
                # a stream is its connection's last answer, as the reference agent's is
                "headers": [
                    (b"content-type", b"multipart/mixed;boundary=" + boundary),
                    (b"connection", b"close"),
                ],
            }
        )
        try:
            quiet_since = asyncio.get_running_loop().time()
            while not gone.is_set() and not self._closing:
                changed = self._changed
                now = asyncio.get_running_loop().time()
                if self.stalled:
                    await _either(changed, gone, interval)
                    continue
                if start < self.first_sequence:
                    # the client fell behind the buffer: say so and end, as the agent does
                    text = f"'from' {start} has left the buffer (first {self.first_sequence})"
                    await send(_part(boundary, self._error("OUT_OF_RANGE", text), last=True))
                    return
                chosen, end = self._chosen(start, count, only)
                if chosen or now - quiet_since >= heartbeat:
                    await send(_part(boundary, self._document(chosen, end, only)))
                    start, quiet_since = end, now
                    await _either(asyncio.Event(), gone, interval)  # at most one per interval
                    continue
                start = end  # other devices' observations: nothing to send for this one
                await _either(changed, gone, heartbeat - (now - quiet_since))
            await send({"type": "http.response.body", "body": b"--" + boundary + b"--\r\n"})
        finally:
            watcher.cancel()


def _part(boundary: bytes, body: bytes, *, last: bool = False) -> Message:
    head = b"--" + boundary + b"\r\nContent-type: text/xml\r\nContent-length: "
    data = head + str(len(body)).encode() + b"\r\n\r\n" + body + b"\r\n"
    if last:
        data += b"--" + boundary + b"--\r\n"
    return {"type": "http.response.body", "body": data, "more_body": not last}


async def _either(first: asyncio.Event, second: asyncio.Event, seconds: float) -> None:
    """Wait until either event is set or ``seconds`` pass."""
    waits = [asyncio.ensure_future(first.wait()), asyncio.ensure_future(second.wait())]
    try:
        await asyncio.wait(waits, timeout=max(seconds, 0), return_when=asyncio.FIRST_COMPLETED)
    finally:
        for wait in waits:
            wait.cancel()


async def _answer(send: Send, status: int, body: bytes) -> None:
    await send(
        {
            "type": "http.response.start",
            "status": status,
            "headers": [(b"content-type", _XML), (b"content-length", str(len(body)).encode())],
        }
    )
    await send({"type": "http.response.body", "body": body})
