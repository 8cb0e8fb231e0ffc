"""The cable's line monitor: what it records, when, and that its files parse back."""

from __future__ import annotations

import errno
import io
import os
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
import serial
from hypothesis import given
from hypothesis import strategies as st

from opendnc.errors import InputError, TransportError
from opendnc.sim.cable import CableProcess, MonitorRecord, VirtualCable, read_monitor
from opendnc.sim.cable.monitor import format_line, parse_monitor
from tests.sim.test_cable import read_exactly

BAUD = 19200
CHAR = 10 / BAUD


@contextmanager
def both_ends(cable: VirtualCable | CableProcess) -> Iterator[tuple[serial.Serial, serial.Serial]]:
    """Sides A and B opened like serial ports (the rate is the cable's business)."""
    a = serial.Serial(cable.path_a, BAUD, timeout=0.2)
    b = serial.Serial(cable.path_b, BAUD, timeout=0.2)
    try:
        yield a, b
    finally:
        a.close()
        b.close()


def test_records_both_directions_with_line_timing(tmp_path: Path) -> None:
    log = tmp_path / "line.txt"
    with VirtualCable(baud=BAUD, monitor=log) as cable, both_ends(cable) as (a, b):
        block = os.urandom(200)
        a.write(block)
        assert read_exactly(b, 200) == block
        b.write(b"\x06")
        assert read_exactly(a, 1) == b"\x06"
    records = read_monitor(log)
    ab = [r for r in records if r.direction == "a>b"]
    ba = [r for r in records if r.direction == "b>a"]
    assert b"".join(r.data for r in ab) == block
    assert ba == [MonitorRecord(ba[0].seconds, "b>a", b"\x06")]
    # the block's bytes leave no sooner than their line time allows, and in order
    times = [r.seconds for r in ab]
    assert times == sorted(times)
    # (the first record's time may come late by a pump stall: bound from its last byte)
    assert times[-1] - times[0] >= (200 - len(ab[0].data) - 1) * CHAR * 0.99
    # the answer was written after the whole block arrived, and takes a character time
    assert ba[0].seconds >= times[-1] + CHAR * 0.99


def test_records_what_the_noise_left(tmp_path: Path) -> None:
    log = tmp_path / "line.txt"
    with VirtualCable(baud=115200, noise=1e-2, drop=1e-2, seed=3, monitor=log) as cable:
        with both_ends(cable) as (a, b):
            a.write(bytes(3000))
            time.sleep(3000 * 10 / 115200)
            assert cable.wait_idle(10)  # the line is empty: all it delivered waits in b's tty
            got = read_exactly(b, cable.stats.a_to_b.delivered)
        stats = cable.stats
    recorded = b"".join(r.data for r in read_monitor(log))
    assert recorded == got  # the monitor shows what the receiver saw, faults included
    assert stats.a_to_b.dropped > 0
    assert stats.a_to_b.corrupted > 0


def test_cable_process_writes_the_monitor(tmp_path: Path) -> None:
    log = tmp_path / "line.txt"
    with CableProcess(baud=230400, monitor=log) as cable, both_ends(cable) as (a, b):
        a.write(b"%\nO01000\n%\n")
        assert read_exactly(b, 11) == b"%\nO01000\n%\n"
    assert b"".join(r.data for r in read_monitor(log)) == b"%\nO01000\n%\n"


def test_unwritable_monitor_is_an_input_error(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="line monitor"):
        VirtualCable(monitor=tmp_path / "no" / "such" / "dir.txt")


def test_cable_process_says_why_it_did_not_start(tmp_path: Path) -> None:
    with pytest.raises(TransportError, match="cannot write the line monitor"):
        CableProcess(monitor=tmp_path / "no" / "such" / "dir.txt").start()


def test_quiet_line_is_flushed_for_live_reading(tmp_path: Path) -> None:
    log = tmp_path / "line.txt"
    with VirtualCable(baud=115200, monitor=log) as cable, both_ends(cable) as (a, b):
        a.write(b"hello")
        assert read_exactly(b, 5) == b"hello"
        deadline = time.monotonic() + 5
        while (
            time.monotonic() < deadline and b"".join(r.data for r in read_monitor(log)) != b"hello"
        ):
            time.sleep(0.01)
        # the cable is still running and the line is quiet: the records are on disk already
        # (one, or more where a loaded machine let the cable read the bytes in pieces)
        assert b"".join(r.data for r in read_monitor(log)) == b"hello"


class FullDisk(io.StringIO):
    def write(self, text: str) -> int:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def test_a_failing_monitor_stops_itself_not_the_cable(tmp_path: Path) -> None:
    log = tmp_path / "line.txt"
    with VirtualCable(baud=115200, monitor=log) as cable, both_ends(cable) as (a, b):
        monitor = cable._monitor
        assert monitor is not None
        monitor._file.close()
        monitor._file = FullDisk()  # type: ignore[assignment]  # as if the disk were full
        a.write(b"still carried")
        assert read_exactly(b, 13) == b"still carried"
        assert cable.running
        assert cable.monitor_error is not None
        assert "stopped" in str(cable.monitor_error)
        assert "No space left" in str(cable.monitor_error)


@pytest.mark.parametrize(
    ("line", "what"),
    [
        ("0.1 a>b", "expected"),
        ("x a>b 06", "bad time"),
        ("-1 a>b 06", "bad time"),
        ("nan a>b 06", "bad time"),
        ("0.1 a<b 06", "bad direction"),
        ("0.1 a>b 0g", "bad hex"),
        ("0.1 a>b  ", "no bytes"),
    ],
)
def test_bad_lines_are_named(line: str, what: str) -> None:
    with pytest.raises(InputError, match=f"line 2: {what}"):
        parse_monitor("0.5 b>a 06\n" + line + "\n")


def test_unreadable_file_is_an_input_error(tmp_path: Path) -> None:
    (tmp_path / "bin").write_bytes(b"\xff\xfe")
    with pytest.raises(InputError, match="cannot read"):
        read_monitor(tmp_path / "bin")


records = st.lists(
    st.builds(
        MonitorRecord,
        st.integers(0, 10**9).map(lambda us: us / 1e6),
        st.sampled_from(["a>b", "b>a"]),
        st.binary(min_size=1, max_size=64),
    )
)


@given(records)
def test_written_lines_parse_back(recs: list[MonitorRecord]) -> None:
    text = "".join(format_line(r.seconds, r.direction, r.data) for r in recs)
    assert parse_monitor(text) == recs


@given(st.text())
def test_any_text_parses_or_names_its_error(text: str) -> None:
    error: InputError | None = None
    try:
        parsed = parse_monitor(text)
    except InputError as exc:
        error, parsed = exc, []
    if error is not None:
        assert "line monitor, line" in str(error)
    assert all(r.data and r.direction in ("a>b", "b>a") for r in parsed)
