"""DPRNT from a program running in the virtual Haas, captured by `opendnc dprnt listen`."""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

from opendnc.haas.mdc import ControlType
from opendnc.sim.haas import HaasConfig
from opendnc.sim.haas.serial_front import SerialOptions, parse_mode

from .conftest import Bench

DPRNT_PROGRAM = """%
O00500 (DPRNT OVER SERIAL)
#100 = 0
POPEN
WHILE [#100 LT 3] DO1
DPRNT[PASS*#100[20]*Z#5023[24]]
#100 = #100 + 1
END1
PCLOS
M30
%
"""


def test_dprnt_captured_by_the_listener_cli(
    bench_factory: Callable[..., Bench], tmp_path: Path
) -> None:
    (tmp_path / "mem").mkdir()
    (tmp_path / "mem" / "O00500.nc").write_text(DPRNT_PROGRAM)
    # a classic control prints DPRNT to its serial port
    config = HaasConfig(control=ControlType.CLASSIC)
    bench = bench_factory(SerialOptions(mode=parse_mode("idle")), config=config)
    listener = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "opendnc.cli.main",
            "dprnt",
            "listen",
            "--port",
            bench.pc_path,
            "--baud",
            "115200",
            "--max-lines",
            "3",
            "--json",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert listener.stderr is not None
        for line in listener.stderr:  # wait until the port is open: earlier bytes are lost
            if "listening on" in line:
                break
        control = bench.sim.sim.control  # type: ignore[union-attr]
        bench.sim.call(lambda: control.start_program(500))
        out, _ = listener.communicate(timeout=20)
    finally:
        if listener.poll() is None:
            listener.kill()
            listener.wait()
    lines = [json.loads(line) for line in out.splitlines() if line.strip()]
    assert [line["line"] for line in lines] == [
        "PASS  0 Z 0.0000",
        "PASS  1 Z 0.0000",
        "PASS  2 Z 0.0000",
    ]
    assert [line["numbers"][0] for line in lines] == [0, 1, 2]
