"""Transports over real loopback sockets and real ptys."""

from __future__ import annotations

import os
import socket
import threading

import pytest

from opendnc.errors import PeerClosed, TransportError, TransportTimeout
from opendnc.transport import SerialStream, TcpStream
from opendnc.transport.pty import open_pty


@pytest.fixture
def listener() -> socket.socket:
    srv = socket.create_server(("127.0.0.1", 0))
    yield srv
    srv.close()


def test_tcp_round_trip_and_peer_close(listener: socket.socket) -> None:
    port = listener.getsockname()[1]

    def echo_once() -> None:
        conn, _ = listener.accept()
        with conn:
            conn.sendall(conn.recv(100).upper())

    thread = threading.Thread(target=echo_once)
    thread.start()
    stream = TcpStream("127.0.0.1", port, timeout=2)
    stream.write(b"t_ok")
    assert stream.read(100) == b"T_OK"
    thread.join()
    with pytest.raises(PeerClosed):
        stream.read(100)
    stream.close()
    stream.close()


def test_tcp_timeout_is_typed(listener: socket.socket) -> None:
    stream = TcpStream("127.0.0.1", listener.getsockname()[1], timeout=0.1)
    with pytest.raises(TransportTimeout):
        stream.read(10)
    stream.close()


def test_tcp_refused_is_transport_error(listener: socket.socket) -> None:
    port = listener.getsockname()[1]
    listener.close()
    with pytest.raises(TransportError, match=f"127.0.0.1:{port}"):
        TcpStream("127.0.0.1", port, timeout=1)


def test_serial_stream_over_pty() -> None:
    pair = open_pty()
    try:
        stream = SerialStream(pair.slave_path, 115200, timeout=0.5)
        os.write(pair.master_fd, b"%\nO1000\n")
        got = b""
        while len(got) < 8:
            got += stream.read(64)
        assert got == b"%\nO1000\n"
        stream.write(b"\x06")
        assert os.read(pair.master_fd, 10) == b"\x06"
        with pytest.raises(TransportTimeout):
            stream.read(1)
        stream.close()
    finally:
        pair.close()


def test_serial_bad_url_is_transport_error() -> None:
    with pytest.raises(TransportError, match="cannot open"):
        SerialStream("/dev/does-not-exist-opendnc")


def test_serial_settings_refused_by_device_is_transport_error() -> None:
    # Once a Linux pty has parity E set, a second tcsetattr with it fails with EINVAL, which
    # pyserial lets escape as termios.error (no OSError): it must become our typed error.
    pair = open_pty()
    try:
        refused = None
        for _ in range(3):
            try:
                SerialStream(pair.slave_path, 9600, parity="E", timeout=0.1).close()
            except TransportError as exc:
                refused = exc
                break
        # A kernel whose pty takes parity E lets every open succeed, which is right as well;
        # what must never happen is a raw termios.error escaping the three opens above.
        if refused is not None:
            assert "refuses 9600 baud, 8E1" in str(refused)
    finally:
        pair.close()


def test_a_read_that_fails_with_eio_is_the_peer_hanging_up() -> None:
    # A pty whose far end closed (rx exiting right after its last ACK) reads EIO.
    import errno

    from opendnc.errors import PeerClosed, TransportError
    from opendnc.transport.serial import _read_error

    hung_up = _read_error("/dev/pts/9", OSError(errno.EIO, "Input/output error"))
    assert isinstance(hung_up, PeerClosed)
    other = _read_error("/dev/pts/9", OSError(errno.EBADF, "Bad file descriptor"))
    assert type(other) is TransportError
    assert "Bad file descriptor" in str(other)
