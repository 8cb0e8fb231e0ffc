"""`opendnc lsv2` against something that is not an LSV2 control says so."""

from __future__ import annotations

import socket
import threading
from collections.abc import Iterator

import pytest
from typer.testing import CliRunner

from opendnc.cli.main import app

HTTP_ANSWER = b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\nConnection: close\r\n\r\n"


@pytest.fixture
def http_server() -> Iterator[int]:
    """A loopback server that answers any request like a web server does."""
    server = socket.create_server(("127.0.0.1", 0))

    def serve() -> None:
        while True:
            try:
                conn, _ = server.accept()
            except OSError:
                return
            with conn:
                conn.recv(4096)
                conn.sendall(HTTP_ANSWER)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        yield server.getsockname()[1]
    finally:
        server.close()
        thread.join(timeout=5)


def test_http_server_is_reported_as_not_an_lsv2_control(http_server: int) -> None:
    result = CliRunner().invoke(app, ["lsv2", "info", "--port", str(http_server), "--timeout", "5"])
    assert result.exit_code == 1
    assert f"127.0.0.1:{http_server} is not an LSV2 control" in result.output
    assert len(result.output.strip().splitlines()) == 1


def test_a_silent_port_asks_whether_it_is_an_lsv2_control() -> None:
    server = socket.create_server(("127.0.0.1", 0))  # accepts (backlog) but never answers
    try:
        port = server.getsockname()[1]
        result = CliRunner().invoke(app, ["lsv2", "info", "--port", str(port), "--timeout", "0.5"])
    finally:
        server.close()
    assert result.exit_code == 1
    assert f"127.0.0.1:{port}: is it an LSV2 control?" in result.output
    assert len(result.output.strip().splitlines()) == 1
