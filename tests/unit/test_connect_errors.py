"""A connection the other side refuses reads as the system's words, the same from every client.

asyncio's own text for a refused connection is "Connect call failed ('127.0.0.1', PORT)", and
a socket's is "[Errno 111] Connection refused"; a machine card or a log line shows "cannot
connect to HOST:PORT: connection refused".
"""

from __future__ import annotations

import asyncio
import errno
import os
import socket

import pytest

from opendnc.errors import TransportError, os_reason
from opendnc.haas.mdc_client import AsyncMdcClient
from opendnc.lsv2.drive import AsyncDriver
from opendnc.transport.tcp import TcpStream


@pytest.fixture
def closed_port() -> int:
    """A loopback port nothing listens on (bound and closed again, not listening)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _expected(port: int) -> str:
    refused = os.strerror(errno.ECONNREFUSED)
    return f"cannot connect to 127.0.0.1:{port}: {refused[0].lower()}{refused[1:]}"


def test_tcp_stream(closed_port: int) -> None:
    with pytest.raises(TransportError) as caught:
        TcpStream("127.0.0.1", closed_port, timeout=2)
    assert str(caught.value) == _expected(closed_port)


def test_mdc_client(closed_port: int) -> None:
    with pytest.raises(TransportError) as caught:
        asyncio.run(AsyncMdcClient.connect("127.0.0.1", closed_port, timeout=2))
    assert str(caught.value) == _expected(closed_port)


def test_lsv2_driver(closed_port: int) -> None:
    with pytest.raises(TransportError) as caught:
        asyncio.run(AsyncDriver.open("127.0.0.1", closed_port, timeout=2))
    assert str(caught.value) == _expected(closed_port)


def test_errors_without_a_number_keep_their_text() -> None:
    assert os_reason(OSError("Bad host")) == "bad host"
    # getaddrinfo's negative codes are not errno values: its own text stays
    assert os_reason(socket.gaierror(-2, "Name or service not known")) == (
        "name or service not known"
    )
