"""The virtual cable's parity model: which characters fail, and what the receiving port gets."""

from __future__ import annotations

import os
import select
import termios
import time

from opendnc.sim.cable import VirtualCable
from opendnc.sim.cable.noise import LineNoise, UartInput, uart_input
from opendnc.transport.marks import MarkDecoder


def test_odd_flips_fail_the_parity_check_even_flips_pass() -> None:
    data = bytes(range(1, 256)) * 40
    plain = LineNoise(ber=0.01, seed=3).apply(data)
    checked = LineNoise(ber=0.01, seed=3, parity_check=True).apply(data)
    assert plain.data == checked.data  # the flips are the same; only the check is added
    assert plain.parity_errors == ()
    pairs = enumerate(zip(data, checked.data, strict=True))
    odd = [i for i, (a, b) in pairs if (a ^ b).bit_count() % 2]
    assert checked.parity_errors == tuple(odd)
    assert len(odd) > 100


def test_parity_errors_count_positions_after_dropped_characters() -> None:
    data = bytes(200) * 50
    result = LineNoise(ber=0.005, drop_rate=0.01, seed=11, parity_check=True).apply(data)
    assert result.dropped > 0
    for i in result.parity_errors:
        # the source was all zeros: a failing character has an odd number of bits set
        assert result.data[i].bit_count() % 2 == 1
    odd = [i for i, c in enumerate(result.data) if c.bit_count() % 2]
    assert list(result.parity_errors) == odd


def test_uart_input_forms() -> None:
    data = b"A\xffB\x05C"
    assert uart_input(data, [2], UartInput.RAW) == data
    assert uart_input(data, [2], UartInput.NUL) == b"A\xff\x00\x05C"
    assert uart_input(data, [2], UartInput.DROP) == b"A\xff\x05C"
    # PARMRK: FF 00 c for the bad character, FF FF for a good FF (termios(3))
    assert uart_input(data, [2], UartInput.MARK) == b"A\xff\xff\xff\x00B\x05C"
    assert uart_input(data, [], UartInput.MARK) == b"A\xff\xffB\x05C"
    decoded = MarkDecoder().decode(uart_input(data, [1, 2], UartInput.MARK))
    assert decoded.data == data
    assert decoded.errors == (1, 2)


def _sender(path: str) -> int:
    """The sending end, raw: what is written goes out as it is."""
    fd = os.open(path, os.O_RDWR | os.O_NOCTTY)
    attrs = termios.tcgetattr(fd)
    attrs[0] = attrs[1] = attrs[3] = 0
    termios.tcsetattr(fd, termios.TCSANOW, attrs)
    return fd


def _slave(path: str, marks: bool) -> int:
    fd = os.open(path, os.O_RDWR | os.O_NOCTTY)
    attrs = termios.tcgetattr(fd)
    attrs[0] = termios.INPCK | (termios.PARMRK if marks else 0)  # raw input otherwise
    attrs[3] = 0
    attrs[6][termios.VMIN], attrs[6][termios.VTIME] = 0, 0
    termios.tcsetattr(fd, termios.TCSANOW, attrs)
    return fd


def _read_all(fd: int, count: int, timeout: float = 5.0) -> bytes:
    got = b""
    deadline = time.monotonic() + timeout
    while len(got) < count and time.monotonic() < deadline:
        if select.select([fd], [], [], 0.05)[0]:
            got += os.read(fd, 4096)
    return got


def test_cable_marks_parity_errors_for_a_port_that_asks_for_marks() -> None:
    """Through real ptys: a PARMRK reader gets FF 00 c and FF FF, decoded back exactly."""
    data = bytes(range(256)) * 8
    with VirtualCable(baud=460800, noise=3e-3, seed=4, parity_check=True) as cable:
        sender = _sender(cable.path_a)
        receiver = _slave(cable.path_b, marks=True)
        try:
            # what the line will do to these bytes, from the same seed
            expected = LineNoise(3e-3, 0.0, "4:a>b", parity_check=True).apply(data)
            want = uart_input(expected.data, expected.parity_errors, UartInput.MARK)
            os.write(sender, data)
            wire = _read_all(receiver, len(want))
        finally:
            os.close(sender)
            os.close(receiver)
    assert expected.parity_errors, "the seed made no parity error"
    assert wire == want
    decoded = MarkDecoder().decode(wire)
    assert decoded.data == expected.data
    assert decoded.errors == expected.parity_errors
    assert cable.stats.parity_failed == len(expected.parity_errors)


def test_cable_hands_nul_to_a_port_with_inpck_alone() -> None:
    data = b"0 BEGIN PGM F MM\r\n" * 200
    with VirtualCable(baud=460800, noise=3e-3, seed=9, parity_check=True) as cable:
        sender = _sender(cable.path_a)
        receiver = _slave(cable.path_b, marks=False)
        try:
            expected = LineNoise(3e-3, 0.0, "9:a>b", parity_check=True).apply(data)
            os.write(sender, data)
            wire = _read_all(receiver, len(data))
        finally:
            os.close(sender)
            os.close(receiver)
    assert expected.parity_errors
    assert wire == uart_input(expected.data, expected.parity_errors, UartInput.NUL)
