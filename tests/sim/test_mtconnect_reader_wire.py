"""The MTConnect reader against a peer that answers badly, over a real loopback socket: every
bad answer ends in a typed error within a deadline, never a hang or an endless loop."""

from __future__ import annotations

import asyncio
from collections.abc import Callable

import pytest

from tests.peers import require_module

require_module("httpx")
require_module("lxml")

from opendnc.errors import DncError, RemoteProtocolError, TransportError  # noqa: E402
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


async def _follow(answer: Answer) -> DncError:
    async def handle(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            head = await reader.readuntil(b"\r\n\r\n")
            path = head.split(b" ", 2)[1].decode()
            writer.write(answer(path))
            await writer.drain()
        except (asyncio.IncompleteReadError, ConnectionError):
            pass
        finally:
            writer.close()

    server = await asyncio.start_server(handle, "127.0.0.1", 0)
    port = server.sockets[0].getsockname()[1]
    client = AgentReader(f"http://127.0.0.1:{port}", heartbeat=0.2, timeout=1.0, grace=0.3)

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
