"""A TCP proxy the test controls, between a server and the real PostgreSQL: it forwards, then
can refuse new connections, freeze (stop forwarding in both directions without closing
anything, as a network that drops every packet looks from both ends) or drop (close every
connection at once, then refuse).

It runs on an asyncio loop of its own thread, listens on loopback only and forwards to
loopback only. Frozen bytes are not lost: they wait in the sockets' buffers and flow on once
the proxy forwards again, as after a network that came back before TCP gave up.
"""

from __future__ import annotations

import asyncio
import contextlib
import threading
from concurrent.futures import Future
from typing import Any

from sqlalchemy.engine import make_url

__all__ = ["DbProxy"]

READ = 65536


class DbProxy:
    """``DbProxy(url)`` listens on 127.0.0.1; :meth:`url_for` is ``url`` through it."""

    def __init__(self, url: str) -> None:
        target = make_url(url)
        assert target.host in ("127.0.0.1", "localhost", "::1"), "loopback only"
        self.target_host = "127.0.0.1" if target.host == "localhost" else str(target.host)
        self.target_port = int(target.port or 5432)
        self.loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self._thread.start()
        self.mode = "forward"  # forward, freeze or refuse
        self.connections = 0
        self._flowing: asyncio.Event | None = None
        self._links: set[asyncio.StreamWriter] = set()
        self._server: asyncio.Server | None = None
        self.port: int = self._call(self._start())

    def _call(self, coro: Any) -> Any:
        future: Future[Any] = asyncio.run_coroutine_threadsafe(coro, self.loop)
        return future.result(10)

    async def _start(self) -> int:
        self._flowing = asyncio.Event()
        self._flowing.set()
        self._server = await asyncio.start_server(self._client, "127.0.0.1", 0)
        port: int = self._server.sockets[0].getsockname()[1]
        return port

    def url_for(self, url: str) -> str:
        """``url`` with its host and port replaced by the proxy's."""
        return (
            make_url(url)
            .set(host="127.0.0.1", port=self.port)
            .render_as_string(hide_password=False)
        )

    # -- what the test does ---------------------------------------------------------------

    def freeze(self) -> None:
        """Stop forwarding, closing nothing; new connections are accepted and left hanging."""
        self._call(self._set("freeze"))

    def refuse(self) -> None:
        """New connections are closed at once; the open ones go on."""
        self._call(self._set("refuse"))

    def drop(self) -> None:
        """Close every connection now and refuse new ones."""
        self._call(self._set("refuse", close=True))

    def restore(self) -> None:
        """Forward again (frozen bytes flow on)."""
        self._call(self._set("forward"))

    async def _set(self, mode: str, close: bool = False) -> None:
        assert self._flowing is not None
        self.mode = mode
        if mode == "forward":
            self._flowing.set()
        else:
            self._flowing.clear()
        if close:
            for writer in list(self._links):
                writer.transport.abort()
            self._links.clear()
            self._flowing.set()  # the pumps of the closed links end at once

    def close(self) -> None:
        async def stop() -> None:
            if self._server is not None:
                self._server.close()
            for writer in list(self._links):
                writer.transport.abort()
            tasks = [t for t in asyncio.all_tasks() if t is not asyncio.current_task()]
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)

        with contextlib.suppress(Exception):
            self._call(stop())
        self.loop.call_soon_threadsafe(self.loop.stop)
        self._thread.join(10)
        self.loop.close()

    # -- forwarding -------------------------------------------------------------------------

    async def _client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        assert self._flowing is not None
        if self.mode == "refuse":
            writer.transport.abort()
            return
        self._links.add(writer)
        await self._flowing.wait()  # a frozen network does not get a connection through
        if self.mode == "refuse" or writer.transport.is_closing():
            writer.transport.abort()
            self._links.discard(writer)
            return
        try:
            up_reader, up_writer = await asyncio.open_connection(self.target_host, self.target_port)
        except OSError:
            writer.transport.abort()
            self._links.discard(writer)
            return
        self.connections += 1
        self._links.add(up_writer)
        await asyncio.gather(
            self._pump(reader, up_writer), self._pump(up_reader, writer), return_exceptions=True
        )
        for side in (writer, up_writer):
            side.transport.abort()
            self._links.discard(side)

    async def _pump(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        assert self._flowing is not None
        while True:
            await self._flowing.wait()
            data = await reader.read(READ)
            if not data:
                writer.transport.abort()
                return
            # a read that began before a freeze is held back until the network is back
            await self._flowing.wait()
            if writer.transport.is_closing():
                return
            writer.write(data)
            await writer.drain()
