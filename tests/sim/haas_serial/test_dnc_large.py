"""A 50 MiB drip-feed under back-pressure: every block executed once, in order, nothing lost."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from opendnc.haas.dnc import DncConfig, stream_program
from opendnc.sim.cable import CableProcess
from opendnc.sim.haas import HaasConfig, SimHaasThread, SimOptions
from opendnc.sim.haas.dnc_link import DncLimits
from opendnc.sim.haas.serial_front import SerialFrontEnd, SerialOptions, parse_mode, start_serial

from .test_dnc_serial import write_program

SIZE = 50 * 2**20
PAD = 440  # ~470-byte blocks: about 110,000 of them


@pytest.mark.slow
def test_fifty_mib_drip_feed(tmp_path: Path) -> None:
    program = tmp_path / "big.nc"
    count = SIZE // (PAD + 34)
    want = write_program(program, count, pad=PAD)
    size = program.stat().st_size
    assert size >= SIZE - 2**20
    options = SerialOptions(mode=parse_mode("dnc"), limits=DncLimits(buffer_blocks=32))
    # The cable in its own process keeps its pump off this interpreter's GIL; its line rate
    # is far above the executor's, so the control's block rate is what throttles the PC.
    with (
        CableProcess(baud=200_000_000) as cable,
        SimHaasThread(HaasConfig(), tmp_path / "mem", SimOptions(mdc_port=None)) as thread,
    ):
        sim = thread.sim
        assert sim is not None

        async def attach() -> SerialFrontEnd:
            front = await start_serial(sim, cable.path_a, 115200, None, options)
            sim.add_front_end(front)
            return front

        front = thread._submit(attach())
        started = time.monotonic()
        report = stream_program(
            cable.path_b,
            program,
            baud=115200,
            safe_mode=False,
            config=DncConfig(chunk=1024),
        )
        deadline = time.monotonic() + 60
        while not front.messages and time.monotonic() < deadline:
            time.sleep(0.05)
        elapsed = time.monotonic() - started
        control = sim.control
        assert front.messages == ["RS232 DONE"]
        assert report.bytes_sent == size
        assert report.xoffs > 10  # flow control really happened, many times
        assert front.xoffs >= report.xoffs
        assert thread.call(lambda: control.machine.get(101)) == want
        assert thread.call(lambda: control.runner.index) == count + 2  # + G21 and M30
        assert thread.call(lambda: list(control.machine.alarms)) == []
        print(f"\n50 MiB drip-feed: {elapsed:.1f} s, {count} blocks, XOFF x{report.xoffs}")
