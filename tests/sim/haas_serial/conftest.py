"""A virtual Haas with its serial front-end on one end of a virtual null-modem cable."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from opendnc.sim.cable import VirtualCable
from opendnc.sim.haas import HaasConfig, SimHaasThread, SimOptions
from opendnc.sim.haas.serial_front import SerialFrontEnd, SerialOptions, start_serial

PROGRAM = """%
O01000 (ROUND TRIP)
G20
G00 G17 G40 G80 G90
T1 M06
G54
S1200 M03
G00 X1. Y1.
G43 H1 Z0.1
M08
G01 Z-0.1 F20.
X2. Y2.
#101 = #101 + 1
G00 Z1.
M09
M05
M30
%
"""


@dataclass
class Bench:
    """The running simulator, its serial front-end and the PC's end of the cable."""

    sim: SimHaasThread
    front: SerialFrontEnd
    cable: VirtualCable
    pc_path: str
    root: Path

    def wait(self, condition: Callable[[], bool], timeout: float = 10.0) -> None:
        """Poll ``condition`` on the simulator's loop until true; fail after ``timeout``."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.sim.call(condition):
                return
            time.sleep(0.01)
        raise AssertionError("condition not reached in time")


def make_bench(
    tmp_path: Path,
    options: SerialOptions,
    *,
    baud: int = 115200,
    block_rate: float = 0.0,
    config: HaasConfig | None = None,
) -> Iterator[Bench]:
    root = tmp_path / "mem"
    root.mkdir(exist_ok=True)
    with VirtualCable(baud=baud) as cable:
        sim_options = SimOptions(mdc_port=0, block_rate=block_rate)
        with SimHaasThread(config or HaasConfig(), root, sim_options) as thread:
            assert thread.sim is not None
            sim = thread.sim

            async def attach() -> SerialFrontEnd:
                front = await start_serial(sim, cable.path_a, options.baud, None, options)
                sim.add_front_end(front)
                return front

            front = thread._submit(attach())
            yield Bench(thread, front, cable, cable.path_b, root)


@pytest.fixture
def bench_factory(tmp_path: Path) -> Iterator[Callable[..., Bench]]:
    gens: list[Iterator[Bench]] = []

    def make(options: SerialOptions, **kwargs: object) -> Bench:
        gen = make_bench(tmp_path, options, **kwargs)  # type: ignore[arg-type]
        gens.append(gen)
        return next(gen)

    yield make
    for gen in reversed(gens):
        gen.close()
