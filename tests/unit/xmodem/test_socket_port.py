"""XModem through a network serial server: `--port socket://HOST:PORT` and `tcp://` over TCP.

The "server" is a loopback listener whose accepted connection runs our engine, as the far
end of a serial server in raw TCP mode would.
"""

from __future__ import annotations

import io
import os
import socket
from collections.abc import Callable
from pathlib import Path

import pytest
from typer.testing import CliRunner

from opendnc.cli.xmodem import app
from opendnc.errors import InputError
from opendnc.transport import TcpStream
from opendnc.transport.base import ByteStream
from opendnc.transport.fd import FdStream
from opendnc.transport.serial import SerialStream, open_stream
from opendnc.xmodem.driver import receive, send
from opendnc.xmodem.framing import Mode
from tests.unit.xmodem.test_driver import Worker


def _serve_once(action: Callable[[ByteStream], object]) -> tuple[int, Worker]:
    """Listen on loopback; the first connection runs ``action`` over an FdStream of it."""
    listener = socket.create_server(("127.0.0.1", 0))
    # a command that never connects must not leave the thread waiting; a loaded machine can
    # take a while to start the command and reach this port (20 s was passed at load 17)
    listener.settimeout(120)

    def run() -> object:
        try:
            conn, _ = listener.accept()
        finally:
            listener.close()
        with conn:
            return action(FdStream(conn.fileno(), timeout=0.05))

    worker = Worker(run)
    worker.start()
    return listener.getsockname()[1], worker


@pytest.mark.parametrize("scheme", ["socket", "tcp"])
def test_cli_send_over_a_socket_url(tmp_path: Path, scheme: str) -> None:
    data = os.urandom(64 * 1024 - 5)
    source = tmp_path / "blob.bin"
    source.write_bytes(data)
    got = io.BytesIO()
    port, peer = _serve_once(lambda stream: receive(stream, got, mode=Mode.ONE_K))
    result = CliRunner().invoke(
        app,
        ["send", "--port", f"{scheme}://127.0.0.1:{port}", str(source), "--mode", "1k", "--binary"],
    )
    assert result.exit_code == 0, result.output
    peer.outcome()
    assert got.getvalue() == data


def test_cli_recv_over_a_socket_url(tmp_path: Path) -> None:
    data = b"%\nO01234(NET)\n" + b"G01 X1. Y2.\n" * 2000 + b"M30\n%\n"
    port, peer = _serve_once(lambda stream: send(stream, data, mode=Mode.CHECKSUM))
    out = tmp_path / "got.nc"
    result = CliRunner().invoke(
        app, ["recv", "--port", f"socket://127.0.0.1:{port}", str(out), "--mode", "checksum"]
    )
    assert result.exit_code == 0, result.output
    peer.outcome()
    assert out.read_bytes() == data


def test_open_stream_picks_tcp_for_plain_socket_urls_only() -> None:
    with socket.create_server(("127.0.0.1", 0)) as listener:
        port = listener.getsockname()[1]
        plain = open_stream(f"socket://127.0.0.1:{port}", timeout=1)
        assert isinstance(plain, TcpStream)
        plain.close()
        # pyserial's own options (here: its logger) keep the URL with pyserial
        with_options = open_stream(f"socket://127.0.0.1:{port}?logging=warning", timeout=1)
        assert isinstance(with_options, SerialStream)
        with_options.close()


@pytest.mark.parametrize(
    "url", ["socket://127.0.0.1", "tcp://:5000", "socket://[::1", "tcp://h:5000?logging=debug"]
)
def test_open_stream_rejects_an_address_without_host_or_port(url: str) -> None:
    with pytest.raises(InputError, match="HOST:PORT"):
        open_stream(url)
