"""Adaptive busy-polling (transport.spin) and the streams using it, on real ptys and sockets."""

from __future__ import annotations

import os
import select
import socket
import struct
import threading
import time
from collections.abc import Callable, Iterator

import pytest

from opendnc.errors import PeerClosed, TransportError, TransportTimeout
from opendnc.transport import TcpStream
from opendnc.transport import spin as spin_module
from opendnc.transport.fd import FdStream
from opendnc.transport.pty import PtyPair, open_pty
from opendnc.transport.spin import BusyPoll


def test_policy_spins_while_answers_are_fast_and_stops_when_they_are_slow(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(spin_module, "_several_cpus", lambda: True)
    poll = BusyPoll(100e-6)
    assert poll.active
    for _ in range(5):
        poll.record(20e-6)
    assert poll.active
    poll.record(2e-3)  # one answer from a slow control is enough to stop spinning
    assert not poll.active
    for _ in range(20):
        poll.record(20e-6)
    assert poll.active  # and fast answers bring it back


def test_policy_is_off_with_a_zero_window_or_a_single_cpu(monkeypatch: pytest.MonkeyPatch) -> None:
    assert not BusyPoll(0).active
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0})
    assert not BusyPoll(100e-6).active


def test_spin_returns_the_first_result_or_none_after_the_window() -> None:
    # a window long enough for three calls on a busy machine: spin returns at the third
    calls = iter([None, None, b"x"])
    assert BusyPoll(10.0).spin(lambda: next(calls), time.perf_counter()) == b"x"
    poll = BusyPoll(5e-3)
    started = time.perf_counter()
    assert poll.spin(lambda: None, started) is None
    assert time.perf_counter() - started >= 5e-3


@pytest.fixture
def pty_pair() -> Iterator[PtyPair]:
    pair = open_pty()
    yield pair
    pair.close()


def test_fd_stream_reads_writes_and_times_out(pty_pair: PtyPair) -> None:
    fd = pty_pair.slave_fd
    stream = FdStream(fd, timeout=0.2)
    try:
        os.write(pty_pair.master_fd, b"\x01\x02")
        assert stream.read(10) == b"\x01\x02"
        stream.write(b"\x06")
        assert os.read(pty_pair.master_fd, 10) == b"\x06"
        started = time.monotonic()
        with pytest.raises(TransportTimeout):
            stream.read(10)
        assert 0.15 < time.monotonic() - started < 2
    finally:
        stream.close()
    assert os.get_blocking(fd)  # the descriptor's flags were never touched


def test_fd_stream_write_larger_than_the_tty_buffer(pty_pair: PtyPair) -> None:
    fd = pty_pair.slave_fd
    stream = FdStream(fd, timeout=5)
    data = os.urandom(1 << 20)
    got = bytearray()

    def drain() -> None:
        while len(got) < len(data):
            got.extend(os.read(pty_pair.master_fd, 65536))

    reader = threading.Thread(target=drain)
    reader.start()
    stream.write(data)
    reader.join(10)
    stream.close()
    assert bytes(got) == data


def test_fd_stream_reports_a_hang_up() -> None:
    pair = open_pty()
    stream = FdStream(pair.slave_fd, timeout=1)
    os.close(pair.master_fd)
    try:
        with pytest.raises(PeerClosed):
            stream.read(10)
    finally:
        os.close(pair.slave_fd)


def _count_spin_hits(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """Make every BusyPoll count the reads its spinning answered (hits[0])."""
    monkeypatch.setattr(spin_module, "_several_cpus", lambda: True)
    hits = [0]
    real_spin = BusyPoll.spin

    def counting(self: BusyPoll, attempt: Callable[[], bytes | None], started: float) -> object:
        result = real_spin(self, attempt, started)
        hits[0] += result is not None
        return result

    monkeypatch.setattr(BusyPoll, "spin", counting)
    return hits


def test_fd_stream_ping_pong_is_answered_by_spinning(
    pty_pair: PtyPair, monkeypatch: pytest.MonkeyPatch
) -> None:
    hits = _count_spin_hits(monkeypatch)
    stream = FdStream(pty_pair.slave_fd, timeout=2, busy_poll=50e-3)
    master = pty_pair.master_fd

    def echo() -> None:
        for _ in range(50):
            os.write(master, os.read(master, 10))

    peer = threading.Thread(target=echo)
    peer.start()
    for i in range(50):
        stream.write(bytes([i]))
        assert stream.read(10) == bytes([i])
    peer.join(5)
    assert hits[0] >= 40  # answers within the window are picked up while spinning


def test_tcp_stream_spins_times_out_and_sees_close(monkeypatch: pytest.MonkeyPatch) -> None:
    hits = _count_spin_hits(monkeypatch)
    with socket.create_server(("127.0.0.1", 0)) as listener:
        stream = TcpStream("127.0.0.1", listener.getsockname()[1], timeout=0.2, busy_poll=50e-3)
        conn, _ = listener.accept()
        started = time.monotonic()
        with pytest.raises(TransportTimeout):
            stream.read(10)
        assert time.monotonic() - started >= 0.15
        assert not stream._spin.active  # a wait that long turns spinning off
        stream._spin.record(-1.0)  # pretend the answers are fast again: the spin path runs
        conn.sendall(b"T_OK")
        assert stream.read(10) == b"T_OK"
        assert hits[0] == 1
        conn.close()
        stream._spin.record(-1.0)
        with pytest.raises(PeerClosed):
            stream.read(10)  # end of stream seen by the non-blocking attempt
        stream.close()


def test_tcp_stream_reset_by_peer_is_peer_closed(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(spin_module, "_several_cpus", lambda: True)
    with socket.create_server(("127.0.0.1", 0)) as listener:
        stream = TcpStream("127.0.0.1", listener.getsockname()[1], timeout=1)
        conn, _ = listener.accept()
        # SO_LINGER 0: close() sends a reset instead of a FIN
        conn.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        conn.close()
        # wait until the reset has arrived (the socket turns readable), not a fixed time
        readable, _, _ = select.select([stream._sock], [], [], 5)
        assert readable, "no reset arrived"
        with pytest.raises(PeerClosed, match="reset"):
            stream.read(10)
        stream.close()


def test_tcp_stream_connect_and_write_timeouts_do_not_follow_a_short_read_timeout() -> None:
    with socket.create_server(("127.0.0.1", 0)) as listener:
        stream = TcpStream("127.0.0.1", listener.getsockname()[1], timeout=0.05)
        conn, _ = listener.accept()
        # more than the socket buffers hold; the peer starts reading after 0.3 s, far past the
        # 50 ms read timeout: the write must wait for it instead of failing
        data = os.urandom(8 << 20)
        got = bytearray()

        def slow_reader() -> None:
            time.sleep(0.3)
            while len(got) < len(data):
                got.extend(conn.recv(1 << 20))

        reader = threading.Thread(target=slow_reader)
        reader.start()
        stream.write(data)
        reader.join(10)
        assert bytes(got) == data
        conn.close()
        stream.close()


def test_tcp_stream_bad_host_is_a_transport_error() -> None:
    with pytest.raises(TransportError, match="cannot connect"):
        TcpStream("a..b", 5000, timeout=1)
