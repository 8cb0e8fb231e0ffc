"""The port dispatcher: which stream each address gets, the errors and hints for bad ones, and
the two calls drip-feed needs (``read_nowait``, ``drain``) on every kind of stream.

Real loopback sockets, real ptys and pyserial's own ``loop://``; no mocks.
"""

from __future__ import annotations

import socket
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from typer.testing import CliRunner

from opendnc.cli.main import app as cli
from opendnc.errors import InputError, PeerClosed, TransportError
from opendnc.haas.dnc import Flow, open_dnc_port
from opendnc.haas.listen import DprntListener
from opendnc.transport import FdStream, PortStream, SerialStream, TcpStream, open_stream
from opendnc.transport import tcp as tcp_module
from opendnc.transport.pty import open_pty


@pytest.fixture
def listener() -> Iterator[socket.socket]:
    server = socket.create_server(("127.0.0.1", 0))
    server.settimeout(10)
    yield server
    server.close()


def _closed_port() -> int:
    """A loopback port nobody listens on (bound, then released)."""
    with socket.create_server(("127.0.0.1", 0)) as probe:
        return int(probe.getsockname()[1])


def _until(read: Callable[[], bytes], want: int, seconds: float = 5.0) -> bytes:
    """Call a non-blocking read until ``want`` bytes came; fail at the deadline."""
    got = b""
    deadline = time.monotonic() + seconds
    while len(got) < want:
        assert time.monotonic() < deadline, f"only {got!r} within {seconds} s"
        got += read()
    return got


@pytest.mark.parametrize("scheme", ["tcp", "socket", "TCP"])
def test_plain_tcp_addresses_get_the_tcp_stream(listener: socket.socket, scheme: str) -> None:
    port = listener.getsockname()[1]
    stream = open_stream(f"{scheme}://127.0.0.1:{port}", 9600, timeout=1)
    try:
        assert isinstance(stream, TcpStream)
        conn, _ = listener.accept()
        with conn:
            conn.sendall(b"\x13")
            assert _until(lambda: stream.read_nowait(10), 1) == b"\x13"
    finally:
        stream.close()


def test_socket_drip_feed_port_is_the_tcp_stream(listener: socket.socket) -> None:
    port = listener.getsockname()[1]
    stream = open_dnc_port(f"socket://127.0.0.1:{port}", 115200, flow=Flow.XONXOFF)
    try:
        assert isinstance(stream, TcpStream)
    finally:
        stream.close()


def test_loop_url_goes_to_pyserial_with_every_setting() -> None:
    stream = open_stream(
        "loop://", 19200, parity="e", bytesize=7, stopbits=2, flow="rtscts", timeout=0.2
    )
    try:
        assert isinstance(stream, SerialStream)
        port = stream.port
        assert (port.baudrate, port.parity, port.bytesize, port.stopbits) == (19200, "E", 7, 2)
        assert port.rtscts
        assert not port.xonxoff
        assert stream.read_nowait(10) == b""
        stream.write(b"G01 X1.\n")
        stream.drain()
        assert _until(lambda: stream.read_nowait(3), 8) == b"G01 X1.\n"
    finally:
        stream.close()


@pytest.mark.parametrize(
    ("url", "message"),
    [
        ("127.0.0.1:5051", r"did you mean tcp://127\.0\.0\.1:5051\?"),
        ("haas-vf2.shop.lan:5051", r"did you mean tcp://haas-vf2\.shop\.lan:5051\?"),
        ("[::1]:5051", r"did you mean tcp://\[::1\]:5051\?"),
        ("http://127.0.0.1:80", r"unknown port type http://"),
        ("tcp://127.0.0.1", r"use tcp://HOST:PORT"),
        ("tcp://127.0.0.1:5051/x", r"use tcp://HOST:PORT"),
        ("tcp://127.0.0.1:5051?logging=debug", r"takes no options"),
        ("socket://:5051", r"use socket://HOST:PORT"),
        ("", r"no port given"),
        ("loop://?logging=loud", r"unknown option value 'loud'"),
    ],
)
def test_malformed_addresses_are_input_errors(url: str, message: str) -> None:
    with pytest.raises(InputError, match=message):
        open_stream(url)


@pytest.mark.parametrize(
    ("settings", "message"),
    [
        ({"parity": "X"}, "unknown parity 'X'"),
        ({"bytesize": 9}, "bad byte size 9"),
        ({"stopbits": 3}, "bad stop bits 3"),
        ({"flow": "dsrdtr"}, "unknown flow control 'dsrdtr'"),
    ],
)
def test_impossible_line_settings_are_input_errors(
    settings: dict[str, object], message: str
) -> None:
    with pytest.raises(InputError, match=message):
        open_stream("loop://", **settings)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("device", "reason"),
    [
        ("/dev/ttyUSB-opendnc-missing", "No such file or directory (is the adapter plugged in?)"),
        ("/dev/null", "(not a serial port)"),
    ],
)
def test_a_device_that_does_not_open_says_why_in_one_line(device: str, reason: str) -> None:
    with pytest.raises(TransportError) as caught:
        open_stream(device)
    message = str(caught.value)
    assert message == f"cannot open serial port {device}: {message.split(': ', 1)[1]}"
    assert message.endswith(reason)
    assert "\n" not in message
    assert message.count(device) == 1  # not pyserial's text wrapped around the OS error


def test_refused_tcp_is_a_transport_error() -> None:
    port = _closed_port()
    with pytest.raises(TransportError, match=f"cannot connect to 127.0.0.1:{port}"):
        open_stream(f"tcp://127.0.0.1:{port}")


@pytest.mark.parametrize("dontwait", [True, False], ids=["msg-dontwait", "select"])
def test_tcp_read_nowait_never_waits_and_sees_a_hang_up(
    listener: socket.socket, dontwait: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    # without MSG_DONTWAIT (Windows) the stream asks select() first
    monkeypatch.setattr(tcp_module, "_CAN_SPIN", dontwait and tcp_module._CAN_SPIN)
    stream = open_stream(f"tcp://127.0.0.1:{listener.getsockname()[1]}", timeout=5)
    conn, _ = listener.accept()
    try:
        started = time.monotonic()
        assert stream.read_nowait(100) == b""
        assert time.monotonic() - started < 1.0  # the 5 s read timeout did not apply
        conn.sendall(b"\x11ok")
        assert _until(lambda: stream.read_nowait(100), 3) == b"\x11ok"
        stream.drain()  # TCP: returns at once
        conn.close()
        with pytest.raises(PeerClosed):
            _until(lambda: stream.read_nowait(100), 1)
    finally:
        stream.close()


def test_pty_streams_read_nowait_and_drain() -> None:
    pair = open_pty()
    streams: list[PortStream] = [
        FdStream(pair.master_fd, timeout=0.2),
        SerialStream(pair.slave_path, 115200, timeout=0.2),
    ]
    try:
        master, slave = streams
        for this, other in ((master, slave), (slave, master)):
            assert this.read_nowait(10) == b""
            other.write(b"\x13" * 100)
            other.drain()  # a tty: waits until the line took it
            assert _until(lambda this=this: this.read_nowait(64), 100) == b"\x13" * 100
    finally:
        streams[1].close()
        pair.close()


class _Refused:
    """An opener whose port never opens; counts the attempts."""

    def __init__(self) -> None:
        self.calls = 0

    def __call__(self, spec: str) -> PortStream:
        self.calls += 1
        raise TransportError(f"cannot open serial port {spec}: No such file or directory")


def test_listener_fails_once_on_a_port_that_never_opened() -> None:
    opener = _Refused()
    listener = DprntListener(
        "/dev/ttyUSB9", [], opener=opener, sleep=lambda s: None, retry_unopened=False
    )
    with pytest.raises(TransportError, match="No such file"):
        listener.run(max_connects=3)
    assert opener.calls == 1


def test_listener_retries_an_unopened_port_when_asked() -> None:
    opener = _Refused()
    slept: list[float] = []

    def sleep(seconds: float) -> None:
        slept.append(seconds)
        if len(slept) == 4:
            listener.stop()

    listener = DprntListener("/dev/ttyUSB9", [], opener=opener, sleep=sleep)
    stats = listener.run()
    assert opener.calls == 4
    assert stats.errors == 4
    assert slept == [0.5, 1.0, 2.0, 4.0]


def test_dprnt_listen_cli_fails_once_with_the_hint() -> None:
    result = CliRunner().invoke(cli, ["dprnt", "listen", "--port", "127.0.0.1:5051"])
    assert result.exit_code == 1
    lines = result.output.strip().splitlines()
    assert lines == [
        "error: no serial port named '127.0.0.1:5051' (did you mean tcp://127.0.0.1:5051?)"
    ]


def test_dprnt_listen_cli_fails_once_on_a_refused_port() -> None:
    port = _closed_port()
    started = time.monotonic()
    result = CliRunner().invoke(cli, ["dprnt", "listen", "--port", f"tcp://127.0.0.1:{port}"])
    assert result.exit_code == 1
    assert result.output.strip().splitlines() == [
        f"error: cannot connect to 127.0.0.1:{port}: connection refused"
    ]
    assert time.monotonic() - started < 5  # no backoff loop ran


def test_host_port_hint_only_when_no_such_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # a device file that happens to be called like an address is opened, not second-guessed
    monkeypatch.chdir(tmp_path)
    (tmp_path / "box:7").write_bytes(b"")
    with pytest.raises(TransportError, match="not a serial port"):
        open_stream("box:7")


@pytest.mark.parametrize(
    "command",
    [
        ["xmodem", "send", "--port", "{port}", "{file}"],
        ["xmodem", "recv", "--port", "{port}", "{out}"],
        ["haas", "dnc", "--unsafe", "--port", "{port}", "{file}"],
        ["dprnt", "listen", "--port", "{port}"],
    ],
    ids=["xmodem-send", "xmodem-recv", "haas-dnc", "dprnt-listen"],
)
@pytest.mark.parametrize(
    ("port", "reason"),
    [
        (
            "127.0.0.1:5051",
            "no serial port named '127.0.0.1:5051' (did you mean tcp://127.0.0.1:5051?)",
        ),
        (
            "/dev/ttyUSB-opendnc-missing",
            "cannot open serial port /dev/ttyUSB-opendnc-missing: No such file or directory"
            " (is the adapter plugged in?)",
        ),
    ],
    ids=["host-port", "missing-device"],
)
def test_every_command_reports_a_port_that_does_not_open_in_one_line(
    command: list[str], port: str, reason: str, tmp_path: Path
) -> None:
    program = tmp_path / "O00010.nc"
    program.write_text("%\nO00010\nM30\n%\n")
    values = {"port": port, "file": str(program), "out": str(tmp_path / "in.nc")}
    result = CliRunner().invoke(cli, [arg.format(**values) for arg in command])
    assert result.exit_code == 1
    assert result.output.splitlines() == [f"error: {reason}"]
