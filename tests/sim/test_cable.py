"""The virtual null-modem cable over real ptys: line rate, full duplex, faults, reopening."""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import serial

from opendnc.errors import InputError, PeerClosed
from opendnc.sim.cable import LineNoise, VirtualCable
from opendnc.transport import SerialStream


def read_exactly(port: serial.Serial, size: int, timeout: float = 5.0) -> bytes:
    got = bytearray()
    deadline = time.monotonic() + timeout
    while len(got) < size and time.monotonic() < deadline:
        got += port.read(size - len(got))
    return bytes(got)


@pytest.fixture
def cable() -> Iterator[VirtualCable]:
    with VirtualCable(baud=19200) as running:
        yield running


def open_port(path: str) -> serial.Serial:
    return serial.Serial(path, 19200, timeout=0.2)


def test_pacing_2kib_at_19200(cable: VirtualCable) -> None:
    a, b = open_port(cable.path_a), open_port(cable.path_b)
    data = os.urandom(2048)
    start = time.monotonic()
    a.write(data)
    got = read_exactly(b, len(data))
    elapsed = time.monotonic() - start
    expected = 2048 * 10 / 19200  # 1.067 s
    assert got == data
    # bytes never leave before their deadline: the lower bound is hard, the upper allows load
    assert expected * 0.995 <= elapsed <= expected * 1.10, elapsed
    assert cable.stats.a_to_b.carried == cable.stats.a_to_b.delivered == 2048
    a.close()
    b.close()


def test_full_duplex_each_direction_at_full_rate(cable: VirtualCable) -> None:
    a, b = open_port(cable.path_a), open_port(cable.path_b)
    to_b, to_a = os.urandom(2048), os.urandom(2048)
    results: dict[str, bytes] = {}

    def receive(name: str, port: serial.Serial) -> None:
        results[name] = read_exactly(port, 2048)

    readers = [
        threading.Thread(target=receive, args=("b", b)),
        threading.Thread(target=receive, args=("a", a)),
    ]
    start = time.monotonic()
    for reader in readers:
        reader.start()
    a.write(to_b)
    b.write(to_a)
    for reader in readers:
        reader.join(5)
    elapsed = time.monotonic() - start
    assert results == {"b": to_b, "a": to_a}
    # both directions at once take as long as one: the lanes do not share the line
    assert elapsed <= 2048 * 10 / 19200 * 1.15, elapsed
    a.close()
    b.close()


def test_rate_follows_bits_per_char() -> None:
    with VirtualCable(baud=115200, bits_per_char=11) as cable:  # 8E1
        assert cable.bytes_per_second == pytest.approx(115200 / 11)
        a, b = open_port(cable.path_a), open_port(cable.path_b)
        data = os.urandom(5000)
        start = time.monotonic()
        a.write(data)
        assert read_exactly(b, len(data)) == data
        elapsed = time.monotonic() - start
        assert 5000 * 11 / 115200 * 0.995 <= elapsed <= 5000 * 11 / 115200 * 1.10, elapsed
        a.close()
        b.close()


def test_single_byte_latency_is_one_character_time() -> None:
    with VirtualCable(baud=9600) as cable:
        a, b = open_port(cable.path_a), open_port(cable.path_b)
        delays = []
        for _ in range(20):
            start = time.monotonic()
            a.write(b"\x06")
            assert read_exactly(b, 1) == b"\x06"
            delays.append(time.monotonic() - start)
        # one character is 1.04 ms at 9600 8N1: never sooner, and a quarter of the bytes
        # within 5 ms more (a loaded machine delays some threads' wake-ups; a cable that
        # held bytes for a period of its own would delay them all)
        assert min(delays) >= 10 / 9600 * 0.99
        assert sorted(delays)[4] < 10 / 9600 + 0.005, delays
        a.close()
        b.close()


def test_noise_through_the_cable_is_counted_and_reproducible() -> None:
    data = os.urandom(20_000)
    received = []
    for _ in range(2):
        with VirtualCable(baud=1_000_000, noise=1e-3, drop=1e-3, seed=11) as cable:
            a, b = open_port(cable.path_a), open_port(cable.path_b)
            a.write(data)
            got = bytearray()
            deadline = time.monotonic() + 5
            while cable.stats.a_to_b.carried < len(data) and time.monotonic() < deadline:
                got += b.read(4096)
            while chunk := b.read(4096):  # the tail (the port times out after 0.2 s)
                got += chunk
            assert cable.wait_idle(1)
            stats = cable.stats.a_to_b
            assert stats.carried == len(data)
            assert stats.delivered == len(got) == len(data) - stats.dropped
            assert stats.dropped > 0
            assert stats.corrupted > 0
            received.append(bytes(got))
            a.close()
            b.close()
    assert received[0] == received[1]
    # and it is exactly what the fault model predicts for this seed and direction
    assert received[0] == LineNoise(1e-3, 1e-3, seed="11:a>b").apply(data).data


def test_slave_closed_and_reopened_on_both_sides(cable: VirtualCable) -> None:
    a, b = open_port(cable.path_a), open_port(cable.path_b)
    a.write(b"first")
    assert read_exactly(b, 5) == b"first"
    b.close()
    a.write(b"nobody listens")  # like a real line with the far port closed: lost
    deadline = time.monotonic() + 3
    while cable.stats.a_to_b.unheard < 14 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert cable.stats.a_to_b.unheard == 14
    b = open_port(cable.path_b)
    a.write(b"second")
    assert read_exactly(b, 6) == b"second"
    # the sending side goes away and comes back (its master reads EIO meanwhile)
    a.close()
    time.sleep(0.05)
    assert cable.running
    a = open_port(cable.path_a)
    b.write(b"back")
    assert read_exactly(a, 4) == b"back"
    a.write(b"again")
    assert read_exactly(b, 5) == b"again"
    a.close()
    b.close()


def test_bytes_written_just_before_close_still_cross(cable: VirtualCable) -> None:
    b = open_port(cable.path_b)
    fd = os.open(cable.path_a, os.O_RDWR | os.O_NOCTTY)
    os.write(fd, b"final ack\x06")
    os.close(fd)
    assert read_exactly(b, 10) == b"final ack\x06"
    b.close()


def test_close_hangs_up_users_and_removes_links(tmp_path: Path) -> None:
    link_a, link_b = tmp_path / "a", tmp_path / "b"
    link_a.symlink_to("/nonexistent-stale-link")  # left over from a killed cable: replaced
    cable = VirtualCable(baud=115200, link_a=link_a, link_b=link_b).start()
    assert os.readlink(link_a) == cable.path_a
    assert os.readlink(link_b) == cable.path_b
    stream = SerialStream(str(link_b), 115200, timeout=2)
    cable.close()
    cable.close()
    assert not cable.running
    assert not link_a.exists()
    assert not link_a.is_symlink()
    assert not link_b.is_symlink()
    with pytest.raises(PeerClosed):
        stream.read(1)
    stream.close()


def test_refuses_to_replace_a_regular_file(tmp_path: Path) -> None:
    keep = tmp_path / "keep"
    keep.write_text("precious")
    with pytest.raises(InputError, match="not a symlink"):
        VirtualCable(link_a=keep)
    assert keep.read_text() == "precious"


@pytest.mark.parametrize(
    "kwargs", [{"baud": 0}, {"bits_per_char": 0}, {"noise": 2.0}, {"drop": -1.0}]
)
def test_bad_settings_are_input_errors(kwargs: dict[str, float]) -> None:
    with pytest.raises(InputError):
        VirtualCable(**kwargs)  # type: ignore[arg-type]


def test_slow_reader_loses_nothing() -> None:
    """A reader that stalls fills the pty; the cable holds back instead of dropping bytes."""
    with VirtualCable(baud=1_000_000) as cable:
        a, b = open_port(cable.path_a), open_port(cable.path_b)
        data = os.urandom(60_000)  # more than the pty, the lane and the sender's pty hold
        writer = threading.Thread(target=a.write, args=(data,))
        writer.start()
        time.sleep(0.8)  # the line needs 0.6 s; nobody reads meanwhile
        assert read_exactly(b, len(data)) == data
        writer.join(5)
        stats = cable.stats.a_to_b
        assert stats.delivered == len(data)
        assert stats.unheard == stats.dropped == 0
        a.close()
        b.close()
