"""MDC Q-commands on a classic Haas's serial port (Setting 143 ON), through the virtual cable."""

from __future__ import annotations

import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from opendnc.errors import TransportTimeout
from opendnc.haas.mdc import ControlType, Count, Mode, ProgramStatus
from opendnc.haas.mdc_client import MdcClient
from opendnc.sim.haas import HaasConfig
from opendnc.sim.haas.serial_front import SerialOptions, parse_mode
from opendnc.sim.haas.serial_xmodem import XmodemQuirks
from opendnc.transport.serial import SerialStream
from opendnc.xmodem.files import send_file
from opendnc.xmodem.framing import Mode as XmodemMode
from opendnc.xmodem.haas import Eob

from .conftest import PROGRAM, Bench

CLASSIC = HaasConfig(control=ControlType.CLASSIC, model="VF-2", serial_number="7654321")
FAST_NAKS = XmodemQuirks(nak_interval=0.2, start_timeout=30)


def _set_state(bench: Bench, program: str, parts: int) -> None:
    def change() -> None:
        machine = bench.sim.sim.control.machine  # type: ignore[union-attr]
        machine.program, machine.m30_counter_1 = program, parts

    bench.sim.call(change)


def _read_until(stream: SerialStream, end: bytes, timeout: float = 3.0) -> bytes:
    got = b""
    deadline = time.monotonic() + timeout
    while not got.endswith(end) and time.monotonic() < deadline:
        try:
            got += stream.read(256)
        except TransportTimeout:
            continue
    return got


def test_idle_port_answers_q500_framed_as_the_classic_control(
    bench_factory: Callable[..., Bench],
) -> None:
    bench = bench_factory(SerialOptions(mode=parse_mode("idle")), config=CLASSIC)
    _set_state(bench, "O01234", 17)
    stream = SerialStream(bench.pc_path, 115200, timeout=0.1)
    try:
        stream.write(b"?Q500\r\n")
        # STX payload ETB CR LF > (docs/haas.md#mdc), nothing else on an idle port
        assert _read_until(stream, b">") == b"\x02PROGRAM, O01234, IDLE, PARTS, 17\x17\r\n>"
        stream.write(b"?Q104\r\n")
        assert _read_until(stream, b">") == b"\x02MODE, (MDI)\x17\r\n>"
        stream.write(b"?Q999\r\n")
        assert _read_until(stream, b">") == b"\x02UNKNOWN\x17\r\n>"
    finally:
        stream.close()
    assert bench.front.messages == []  # an MDC exchange is no RS232 job


def test_serial_client_reads_status_and_macros(bench_factory: Callable[..., Bench]) -> None:
    bench = bench_factory(SerialOptions(mode=parse_mode("idle")), config=CLASSIC)
    _set_state(bench, "O00042", 3)
    bench.sim.call(lambda: bench.sim.sim.control.machine.set(101, 2.5))  # type: ignore[union-attr]
    with MdcClient.open_serial(bench.pc_path, 115200, timeout=2.0) as client:
        reply = client.query(500)
        assert reply == ProgramStatus("O00042", "IDLE", 3)
        assert client.macro_get(101) == 2.5
        summary = client.status()
    assert (summary.serial, summary.model, summary.mode) == ("7654321", "VF-2", "MDI")
    assert (summary.program, summary.parts) == ("O00042", 3)
    assert bench.front.mdc_replies >= 3


def test_auto_port_answers_between_xmodem_transfers(
    bench_factory: Callable[..., Bench], tmp_path: Path
) -> None:
    options = SerialOptions(baud=115200, mode=parse_mode("auto"), quirks=FAST_NAKS)
    bench = bench_factory(options, config=CLASSIC)
    _set_state(bench, "O00007", 5)
    time.sleep(0.5)  # the waiting receiver's NAKs are on the line before the request
    stream = SerialStream(bench.pc_path, 115200, timeout=0.1)
    client = MdcClient.over(stream, timeout=2.0)
    try:
        assert client.query(500) == ProgramStatus("O00007", "IDLE", 5)
        assert client.query(104) == Mode("MDI", parenthesized=True)
        assert client.query(201) == Count("USING TOOL", 0)
    finally:
        stream.close()
    # the port went back to waiting for XModem: a program still arrives whole
    source = tmp_path / "O01000.nc"
    source.write_text(PROGRAM)
    send_file(bench.pc_path, source, mode=XmodemMode.CHECKSUM, baud=115200, eob=Eob.LF)
    bench.wait(lambda: bench.front.programs == [1000])
    assert (bench.root / "O01000.nc").read_text() == PROGRAM
    assert bench.front.messages == ["RS232 DONE"]  # the MDC exchanges were no jobs


@pytest.mark.parametrize("case", ["setting-143-off", "ngc"])
def test_no_answer_without_setting_143_or_on_ngc(
    bench_factory: Callable[..., Bench], case: str
) -> None:
    config = CLASSIC if case == "setting-143-off" else HaasConfig(control=ControlType.NGC)
    bench = bench_factory(SerialOptions(mode=parse_mode("idle")), config=config)
    if case == "setting-143-off":
        control = bench.sim.sim.control  # type: ignore[union-attr]
        bench.sim.call(lambda: control.machine.settings.__setitem__(143, 0))
    with (
        MdcClient.open_serial(bench.pc_path, 115200, timeout=0.5) as client,
        pytest.raises(TransportTimeout, match=r"no MDC reply to \?Q500"),
    ):
        client.query(500)
    assert bench.front.mdc_replies == 0


def test_cli_q_over_the_serial_port(bench_factory: Callable[..., Bench]) -> None:
    bench = bench_factory(SerialOptions(mode=parse_mode("idle")), config=CLASSIC)
    _set_state(bench, "O01234", 9)
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "opendnc.cli.main",
            "haas",
            "q",
            "Q500",
            "--port",
            bench.pc_path,
            "--baud",
            "115200",
        ],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "PROGRAM, O01234, IDLE, PARTS, 9"
