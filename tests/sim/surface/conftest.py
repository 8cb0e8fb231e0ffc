"""A virtual Haas probing a known surface: a tilted plane with a bump, with probe noise."""

from __future__ import annotations

import math
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest

from opendnc.sim.haas import DprntDestination, HaasConfig, SimHaasThread, SimOptions
from opendnc.sim.haas.control import HaasControl
from opendnc.sim.haas.runner import DprntLine, RunnerEvent
from opendnc.surface.grid import Grid

CLI = [sys.executable, "-m", "opendnc.cli.main"]
GRID = Grid(8, 6, 0.5, 0.5, 0.25, 0.25)
GRID_ARGS = ["--grid", "8x6", "--pitch", "0.5", "--origin", "0.25,0.25", "--clearance", "1"]
NOISE_UM = 1.0
SIGMA_IN = NOISE_UM / 25400


def surface(x: float, y: float) -> float:
    """Machine Z of the part (inch): tilted plane plus a 0.003 in bump near X1.9 Y1.3."""
    bump = 0.003 * math.exp(-((x - 1.9) ** 2 + (y - 1.3) ** 2) / (2 * 0.35**2))
    return -0.02 + 0.0008 * x - 0.0005 * y + bump


def analytic(grid: Grid) -> dict[str, float]:
    """Plane, tilt and flatness of the exact surface sampled on ``grid`` (no noise)."""
    x = np.array([p.x for p in grid.points])
    y = np.array([p.y for p in grid.points])
    z = np.array([surface(p.x, p.y) for p in grid.points])
    design = np.column_stack([x, y, np.ones_like(x)])
    (a, b, c), *_ = np.linalg.lstsq(design, z, rcond=None)
    residual = z - design @ np.array([a, b, c])
    return {"a": a, "b": b, "c": c, "flatness": float(residual.max() - residual.min())}


@dataclass
class Haas:
    """The running virtual Haas and every DPRNT line it printed."""

    thread: SimHaasThread
    root: Path
    printed: list[str] = field(default_factory=list)

    @property
    def control(self) -> HaasControl:
        assert self.thread.sim is not None
        return self.thread.sim.control

    def start(self, number: int) -> None:
        """The operator's cycle start."""
        self.thread.call(lambda: self.control.start_program(number))

    def wait_idle(self, timeout: float = 30.0) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if not self.thread.call(lambda: self.control.running):
                return
            time.sleep(0.05)
        raise AssertionError("program still running")


def make_haas(tmp_path: Path, config: HaasConfig, options: SimOptions) -> Iterator[Haas]:
    root = tmp_path / "mem"
    root.mkdir(exist_ok=True)
    with SimHaasThread(config, root, options) as thread:
        haas = Haas(thread, root)

        def hook(event: RunnerEvent) -> None:
            if isinstance(event, DprntLine):
                haas.printed.append(event.text)

        thread.call(lambda: haas.control.event_hooks.append(hook))
        yield haas


def probing_config(destination: DprntDestination) -> HaasConfig:
    return HaasConfig(
        surface=surface,
        strict_probe=True,
        probe_noise_um=NOISE_UM,
        probe_seed=14,
        dprnt=destination,
    )


@pytest.fixture
def tcp_haas(tmp_path: Path) -> Iterator[Haas]:
    """An NGC printing DPRNT to a TCP port (Setting 261 = 2)."""
    options = SimOptions(mdc_port=0, dprnt_tcp_port=0)
    yield from make_haas(tmp_path, probing_config(DprntDestination.TCP), options)


def dprnt_port(haas: Haas) -> int:
    assert haas.thread.sim is not None
    assert haas.thread.sim.dprnt_tcp is not None
    return haas.thread.sim.dprnt_tcp.port


def run_until(
    args: list[str], ready: str, action: Callable[[], None], timeout: float = 90
) -> subprocess.CompletedProcess[str]:
    """Run the CLI; when a stderr line contains ``ready``, do ``action``; wait for the end."""
    proc = subprocess.Popen(
        [*CLI, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    seen: list[str] = []
    try:
        assert proc.stderr is not None
        for line in proc.stderr:
            seen.append(line)
            if ready in line:
                action()
                break
        out, err = proc.communicate(timeout=timeout)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return subprocess.CompletedProcess(proc.args, proc.returncode, out, "".join(seen) + err)
