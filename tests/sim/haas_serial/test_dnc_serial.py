"""Drip-feed into the virtual Haas: back-pressure, restart, broken links, XModem DNC."""

from __future__ import annotations

import os
import select
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from opendnc.errors import TransportTimeout
from opendnc.haas.dnc import DncConfig, DncEvent, Flow, Paused, stream_program
from opendnc.haas.mdc import Busy, ProgramStatus
from opendnc.haas.mdc_client import MdcClient
from opendnc.sim.haas import ALARM_DNC_LINK, HaasConfig, SimHaasThread, SimOptions
from opendnc.sim.haas.dnc_link import DncLimits
from opendnc.sim.haas.serial_front import (
    ALARM_DNC_OVERRUN,
    SerialFrontEnd,
    SerialOptions,
    parse_mode,
    start_serial,
)
from opendnc.transport.pty import open_pty
from opendnc.transport.serial import SerialStream
from opendnc.xmodem.files import send_file
from opendnc.xmodem.framing import Mode

from .conftest import Bench

MOD = 1000003


def order_lines(count: int, pad: int = 0) -> Iterator[tuple[str, int]]:
    """Blocks whose macro result depends on running every one of them, once, in order."""
    comment = f" ({'P' * pad})" if pad else ""
    for k in range(count):
        yield f"#101 = [#101 * 3 + {k % 1000}] MOD {MOD}{comment}", k % 1000


def expected(keys: list[int]) -> float:
    value = 0
    for key in keys:
        value = (value * 3 + key) % MOD
    return float(value)


def write_program(path: Path, count: int, number: int = 2000, pad: int = 0) -> float:
    keys = []
    with path.open("w") as handle:
        handle.write(f"%\nO{number:05d} (DNC TEST)\nG21\n")
        for line, key in order_lines(count, pad):
            handle.write(line + "\n")
            keys.append(key)
        handle.write("M30\n%\n")
    return expected(keys)


def q500(bench: Bench) -> object:
    assert bench.sim.sim is not None
    assert bench.sim.sim.mdc is not None
    with MdcClient("127.0.0.1", bench.sim.sim.mdc.port, timeout=3) as client:
        return client.query(500)


def dnc_options(**kwargs: object) -> SerialOptions:
    return SerialOptions(baud=115200, mode=parse_mode("dnc"), **kwargs)  # type: ignore[arg-type]


def test_back_pressure_every_block_in_order(
    bench_factory: Callable[..., Bench], tmp_path: Path
) -> None:
    # The program must outgrow what a pty and the cable buffer (about 70 KB), or the PC has
    # written everything before the control could ask it to wait; and the control must run
    # clearly slower than the line (here 4 s against 1.2 s) or a loaded machine's slower PC
    # side never meets the XOFF.
    limits = DncLimits(buffer_blocks=16, resume_blocks=4)
    bench = bench_factory(dnc_options(limits=limits), baud=2_000_000, block_rate=250)
    program = tmp_path / "p.nc"
    want = write_program(program, 1000, pad=200)
    report = stream_program(
        bench.pc_path, program, baud=115200, safe_mode=False, config=DncConfig(chunk=64)
    )
    assert report.xoffs > 0  # the control's block rate was felt as XOFF
    assert report.paused_seconds > 0.1
    bench.wait(lambda: bench.front.messages == ["RS232 DONE"])
    control = bench.sim.sim.control  # type: ignore[union-attr]
    # every DC3 the PC saw was sent by the control; the last may come after the PC finished
    assert 1 <= report.xoffs <= bench.front.xoffs
    assert bench.sim.call(lambda: control.machine.get(101)) == want
    assert bench.sim.call(lambda: control.runner.index) == 1002  # G21 + 1000 + M30
    status = q500(bench)
    assert isinstance(status, ProgramStatus)
    assert (status.program, status.status, status.parts) == ("O02000", "IDLE", 1)


def test_restart_from_line(bench_factory: Callable[..., Bench], tmp_path: Path) -> None:
    bench = bench_factory(dnc_options())
    program = tmp_path / "p.nc"
    program.write_text(
        "%\nO03000 (RESTART)\nG20\nT4 M06\nG55\nS1500 M03\nM08\n"
        "#101 = 1\n#101 = #101 * 10 + 2\n#101 = #101 * 10 + 3\n#101 = #101 * 10 + 4\nM30\n%\n"
    )
    report = stream_program(
        bench.pc_path,
        program,
        from_line=10,
        baud=115200,
        safe_mode=False,
        config=DncConfig(retract=False),
    )
    assert report.restart is not None
    bench.wait(lambda: bench.front.messages == ["RS232 DONE"])
    control = bench.sim.sim.control  # type: ignore[union-attr]
    source = control.runner.source
    received = bench.sim.call(lambda: [source.block(i).source for i in range(len(source))])
    assert received == [
        "(OPENDNC RESTART AT LINE 10)",
        "G20",
        "G00 G17 G40 G80 G90",
        "T4 M06",
        "G55",
        "S1500 M03",
        "M08",
        "#101 = #101 * 10 + 3",
        "#101 = #101 * 10 + 4",
        "M30",
    ]
    machine = control.machine
    # lines 8 and 9 were skipped: #101 starts empty (0), then *10+3, *10+4
    assert bench.sim.call(lambda: machine.get(101)) == 34.0
    assert bench.sim.call(lambda: (machine.tool, machine.work_offset, machine.spindle_rpm)) == (
        4,
        55,
        1500.0,
    )


def test_silence_mid_stream_raises_the_link_alarm(bench_factory: Callable[..., Bench]) -> None:
    bench = bench_factory(dnc_options(dnc_timeout=0.5))
    stream = SerialStream(bench.pc_path, 115200, timeout=0.1)
    try:
        stream.write(b"%\nO04000 (BROKEN)\nG01 X1. F10.\n")  # ... and then nothing
        bench.wait(lambda: bool(bench.front.messages), timeout=5)
    finally:
        stream.close()
    assert bench.front.messages[0] == "RS232 ABORT DNC link lost (timeout)"
    control = bench.sim.sim.control  # type: ignore[union-attr]
    assert bench.sim.call(lambda: list(control.machine.alarms)) == [ALARM_DNC_LINK]
    status = q500(bench)
    assert isinstance(status, ProgramStatus)
    assert status.status == "ALARM ON"
    assert status.program == "O04000"


def test_port_closing_mid_stream_raises_the_link_alarm(tmp_path: Path) -> None:
    pair = open_pty()  # the sim takes the slave; closing the master is the cable pulled out
    root = tmp_path / "mem"
    with SimHaasThread(HaasConfig(), root, SimOptions(mdc_port=None)) as thread:
        sim = thread.sim
        assert sim is not None

        async def attach() -> SerialFrontEnd:
            front = await start_serial(sim, pair.slave_path, 115200, None, dnc_options())
            sim.add_front_end(front)
            return front

        front = thread._submit(attach())
        os.write(pair.master_fd, b"%\nO04001\nG01 X1. F10.\n")
        deadline = time.monotonic() + 5
        while not thread.call(lambda: sim.control.running) and time.monotonic() < deadline:
            time.sleep(0.01)
        assert thread.call(lambda: sim.control.running), "the DNC program never started"
        os.close(pair.master_fd)
        while not front.messages and time.monotonic() < deadline:
            time.sleep(0.01)
        assert front.messages[0] == "RS232 ABORT DNC link lost (port closed)"
        assert thread.call(lambda: list(sim.control.machine.alarms)) == [ALARM_DNC_LINK]
    pair.close()


def test_sender_ignoring_xoff_overruns_the_buffer(
    bench_factory: Callable[..., Bench], tmp_path: Path
) -> None:
    limits = DncLimits(buffer_blocks=8, resume_blocks=2, overrun_blocks=32)
    bench = bench_factory(dnc_options(limits=limits), block_rate=50)
    program = tmp_path / "p.nc"
    write_program(program, 300)
    config = DncConfig(flow=Flow.NONE, chunk=4096, drain=False)
    stream_program(bench.pc_path, program, baud=115200, safe_mode=False, config=config)
    bench.wait(lambda: bool(bench.front.messages))
    assert bench.front.messages[0] == "RS232 ABORT DNC buffer overrun: the sender ignored XOFF"
    control = bench.sim.sim.control  # type: ignore[union-attr]
    assert bench.sim.call(lambda: list(control.machine.alarms)) == [ALARM_DNC_OVERRUN]


def test_xoff_held_too_long_is_a_clear_error(tmp_path: Path) -> None:
    pair = open_pty()
    program = tmp_path / "p.nc"
    write_program(program, 2000)
    got = bytearray()
    done = threading.Event()

    def control() -> None:
        # a control that stops the PC after its first kilobyte and never resumes
        while not done.is_set():
            if select.select([pair.master_fd], [], [], 0.05)[0]:
                got.extend(os.read(pair.master_fd, 4096))
                if len(got) >= 1024 and b"\x13" not in got:
                    os.write(pair.master_fd, b"\x13")
                    got.extend(b"\x13")

    reader = threading.Thread(target=control, daemon=True)
    reader.start()
    events: list[DncEvent] = []
    try:
        with pytest.raises(TransportTimeout, match="held XOFF"):
            stream_program(
                pair.slave_path,
                program,
                safe_mode=False,
                config=DncConfig(xoff_timeout=0.3, drain=False, chunk=64),
                on_event=events.append,
            )
    finally:
        done.set()
        reader.join(2)
        # collect what the PC wrote and the reader had not read yet (the pty keeps it)
        while select.select([pair.master_fd], [], [], 0)[0]:
            try:
                chunk = os.read(pair.master_fd, 4096)
            except OSError:  # EIO: the PC side is closed and nothing is left
                break
            if not chunk:
                break
            got.extend(chunk)
        pair.close()
    # not one byte was written after the PC saw the XOFF
    assert len(events) == 1
    assert isinstance(events[0], Paused)
    assert len(got) - 1 == events[0].sent


def test_dnc_over_xmodem(bench_factory: Callable[..., Bench], tmp_path: Path) -> None:
    limits = DncLimits(buffer_blocks=8, resume_blocks=2)
    options = SerialOptions(baud=115200, mode=parse_mode("dnc-xmodem"), limits=limits)
    bench = bench_factory(options, block_rate=2000)
    program = tmp_path / "p.nc"
    want = write_program(program, 400)
    send_file(bench.pc_path, program, mode=Mode.CHECKSUM, baud=115200)
    bench.wait(lambda: bench.front.messages == ["RS232 DONE"])
    control = bench.sim.sim.control  # type: ignore[union-attr]
    assert bench.sim.call(lambda: control.machine.get(101)) == want
    assert bench.sim.call(lambda: control.machine.m30_counter_1) == 1


def test_auto_mode_runs_text_as_dnc(bench_factory: Callable[..., Bench], tmp_path: Path) -> None:
    options = SerialOptions(baud=115200, mode=parse_mode("auto"))
    bench = bench_factory(options)
    program = tmp_path / "p.nc"
    want = write_program(program, 100)
    stream_program(bench.pc_path, program, baud=115200, safe_mode=False)
    bench.wait(lambda: bench.front.messages == ["RS232 DONE"])
    control = bench.sim.sim.control  # type: ignore[union-attr]
    assert bench.sim.call(lambda: control.machine.get(101)) == want
    assert bench.front.programs == []  # executed, not stored


def test_busy_while_streaming(bench_factory: Callable[..., Bench], tmp_path: Path) -> None:
    bench = bench_factory(dnc_options(), block_rate=20)
    stream = SerialStream(bench.pc_path, 115200, timeout=0.1)
    try:
        stream.write(b"%\nO05000\nG01 X1. F10.\nG01 X2.\n")
        bench.wait(lambda: bench.sim.sim.control.running)  # type: ignore[union-attr]
        assert isinstance(q500(bench), Busy)
        stream.write(b"M30\n%\n")
        bench.wait(lambda: bench.front.messages == ["RS232 DONE"])
    finally:
        stream.close()
