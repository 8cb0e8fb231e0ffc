"""The virtual Fanuc on one end of a virtual cable, the PC's port on the other."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from opendnc.sim.cable import VirtualCable
from opendnc.sim.fanuc import FanucOptions, FanucParams, Selection, VirtualFanuc
from opendnc.tape.profiles import Profile
from opendnc.tape.serial_io import open_tape_port
from opendnc.transport.base import PortStream

BAUD = 115200


@dataclass
class Bench:
    """The cable, the virtual control and the PC's open port."""

    cable: VirtualCable
    sim: VirtualFanuc
    pc: PortStream
    profile: Profile


@contextmanager
def bench(
    profile: Profile,
    root: Path,
    *,
    options: FanucOptions | None = None,
    params: FanucParams | None = None,
    mode: Selection | None = None,
    noise: float = 0.0,
    seed: int | None = None,
    baud: int = BAUD,
) -> Iterator[Bench]:
    """A running bench (115200 baud by default) with ``profile``'s character frame."""
    line = profile.with_changes(baud=baud)
    with VirtualCable(baud, line.bits_per_char, noise=noise, seed=seed) as cable:
        pc = open_tape_port(cable.path_b, line)  # open before the control speaks
        sim = VirtualFanuc(
            cable.path_a, root, profile=line, params=params, options=options, mode=mode
        )
        try:
            with sim:
                yield Bench(cable, sim, pc, line)
        finally:
            pc.close()


def wait_for(check: Callable[[], bool], timeout: float = 10.0) -> None:
    """Poll ``check`` until it holds, with a deadline."""
    deadline = time.monotonic() + timeout
    while not check():
        if time.monotonic() > deadline:
            raise AssertionError("condition not met in time")
        time.sleep(0.01)
