"""The MTConnect reader against a peer that answers badly, over a real loopback socket: every
bad answer ends in a typed error within a deadline, never a hang or an endless loop."""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import Awaitable, Callable
from typing import Any

import pytest

from tests.peers import require_module

require_module("httpx")
require_module("lxml")

from opendnc.errors import (  # noqa: E402
    DncError,
    RemoteProtocolError,
    TransportError,
    TransportTimeout,
)
from opendnc.mtconnect.reader import AgentReader  # noqa: E402
from tests.unit.test_mtconnect_documents import CURRENT, PROBE  # noqa: E402

Answer = Callable[[str], bytes]  # request path -> the raw bytes sent back (then closed)


def _http(body: bytes, content_type: bytes = b"text/xml") -> bytes:
    head = b"HTTP/1.1 200 OK\r\nContent-Type: " + content_type
    return head + b"\r\nContent-Length: %d\r\nConnection: close\r\n\r\n" % len(body) + body


def _stream(*parts: bytes) -> bytes:
    """A multipart answer of raw ``parts``, then the connection closes (no closing line)."""
    head = b"HTTP/1.1 200 OK\r\nContent-Type: multipart/mixed;boundary=BND\r\n"
    return head + b"Connection: close\r\n\r\n" + b"".join(parts)


def _part(document: bytes) -> bytes:
    return b"--BND\r\nContent-length: %d\r\n\r\n%s\r\n" % (len(document), document)


def _agent(sample: bytes) -> Answer:
    """A peer that probes and reads current well, and answers every sample with ``sample``."""

    def answer(path: str) -> bytes:
        if "/probe" in path:
            return _http(PROBE)
        if "/current" in path:
            return _http(CURRENT)
        return sample

    return answer


Send = Callable[[str, asyncio.StreamWriter], Awaitable[None]]  # writes the answer to a path


async def _follow(answer: Answer) -> DncError:
    async def send(path: str, writer: asyncio.StreamWriter) -> None:
        writer.write(answer(path))
        await writer.drain()

    return await _follow_peer(send)


async def _follow_peer(send: Send, **options: Any) -> DncError:
    handlers: set[asyncio.Task[Any]] = set()

    async def handle(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        handlers.add(task)
        try:
            head = await reader.readuntil(b"\r\n\r\n")
            await send(head.split(b" ", 2)[1].decode(), writer)
        except (asyncio.IncompleteReadError, ConnectionError):
            pass
        finally:
            writer.close()
            with contextlib.suppress(Exception, asyncio.CancelledError):
                await writer.wait_closed()

    server = await asyncio.start_server(handle, "127.0.0.1", 0)
    port = server.sockets[0].getsockname()[1]
    settings: dict[str, Any] = {"heartbeat": 0.2, "timeout": 1.0, "grace": 0.3, **options}
    client = AgentReader(f"http://127.0.0.1:{port}", **settings)

    async def read() -> None:
        await client.open()
        await client.follow()

    try:
        async with asyncio.timeout(10):
            with pytest.raises(DncError) as caught:
                await read()
        return caught.value
    finally:
        await client.close()
        server.close()
        # a sender still writing (an endless answer) is stopped and its socket closed here,
        # not left to the garbage collector during some later test
        for task in handlers:
            task.cancel()
        await asyncio.gather(*handlers, return_exceptions=True)
        await server.wait_closed()


@pytest.mark.parametrize(
    ("answer", "kind", "words"),
    [
        (lambda path: b"SSH-2.0-OpenSSH_9.2\r\n", TransportError, "cannot read the agent"),
        (lambda path: _http(b"<html>login</html>"), RemoteProtocolError, "not an MTConnect"),
        (
            _agent(_stream(b"--BND\r\nContent-type: text/xml\r\n\r\n<x/>\r\n")),
            RemoteProtocolError,
            "without Content-length",
        ),
        (
            _agent(_stream(b"--BND\r\nContent-length: 9\r\n\r\nnot xml!!\r\n")),
            RemoteProtocolError,
            "not well-formed",
        ),
        # streams that end at once, again and again: given up, not asked forever
        (_agent(_stream()), RemoteProtocolError, "brings nothing"),
        # every sample from another instance than probe and current say (two agents in turn)
        (
            _agent(_stream(_part(CURRENT.replace(b'instanceId="17"', b'instanceId="18"')))),
            RemoteProtocolError,
            "brings nothing",
        ),
        (_agent(_stream(b"--BND--\r\n")), RemoteProtocolError, "brings nothing"),
        (_agent(_http(b"", b"multipart/mixed")), RemoteProtocolError, "without a boundary"),
    ],
)
def test_a_bad_answer_is_a_typed_error(answer: Answer, kind: type[DncError], words: str) -> None:
    error = asyncio.run(_follow(answer))
    assert isinstance(error, kind), repr(error)
    assert words in str(error)


_PLAIN_HEAD = b"HTTP/1.1 200 OK\r\nContent-Type: text/xml\r\nConnection: close\r\n\r\n"


def _endless(on: str, *, chunk: bytes, pause: float) -> Send:
    """A peer that answers probe and current well, but ``on`` (a request's word) with a
    plain body of ``chunk`` after ``chunk`` for ever, ``pause`` seconds apart (until the
    client goes)."""

    async def send(path: str, writer: asyncio.StreamWriter) -> None:
        if on not in path:
            writer.write(_agent(b"")(path))
            await writer.drain()
            return
        writer.write(_PLAIN_HEAD + b"<MTConnectStreams>")
        while True:
            writer.write(chunk)
            await writer.drain()
            # the peer's pace (a slow trickle, or a flood that leaves the loop a turn)
            await asyncio.sleep(pause)

    return send


async def _declared_huge(path: str, writer: asyncio.StreamWriter) -> None:
    """Probe answered well; everything else says a body of 1 GB is coming (and sends none)."""
    if "probe" in path:
        writer.write(_http(PROBE))
    else:
        writer.write(
            b"HTTP/1.1 200 OK\r\nContent-Type: text/xml\r\nContent-Length: 1000000000\r\n\r\n"
        )
    await writer.drain()
    await writer.wait_closed()  # held open until the client goes: it must not wait for it


async def _trickled_part(path: str, writer: asyncio.StreamWriter) -> None:
    """Probe and current answered well; the sample stream's first part comes a byte at a
    time, each well within the read timeout."""
    if "sample" not in path:
        writer.write(_agent(b"")(path))
        await writer.drain()
        return
    writer.write(_stream(b"--BND\r\nContent-length: 100000\r\n\r\n"))
    while True:
        writer.write(b" ")
        await writer.drain()
        await asyncio.sleep(0.05)  # the peer's pace


@pytest.mark.parametrize(
    ("send", "kind", "words"),
    [
        # a wrong URL or a broken agent: a plain body that never ends, fast
        (_endless("probe", chunk=b" " * 65536, pause=0), RemoteProtocolError, "larger than"),
        (_endless("sample", chunk=b" " * 65536, pause=0), RemoteProtocolError, "larger than"),
        # a body said to be too large is refused before it is read
        (_declared_huge, RemoteProtocolError, "larger than"),
        # a byte at a time, each well within the read timeout: the document's deadline ends it
        (_endless("current", chunk=b" ", pause=0.05), TransportTimeout, "within 0.5 s"),
        (_endless("sample", chunk=b" ", pause=0.05), TransportTimeout, "within 0.5 s"),
        # one streamed document trickled the same way
        (_trickled_part, TransportTimeout, "within 0.5 s"),
    ],
)
def test_an_endless_plain_answer_is_a_typed_error_in_time(
    send: Send, kind: type[DncError], words: str
) -> None:
    started = time.monotonic()
    error = asyncio.run(_follow_peer(send, max_document=256 * 1024, deadline=0.5))
    assert isinstance(error, kind), repr(error)
    assert words in str(error)
    assert time.monotonic() - started < 5
