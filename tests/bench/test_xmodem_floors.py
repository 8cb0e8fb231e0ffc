"""The floors that ``benchmarks/xmodem.py`` compares the implementations with actually run.

Only that they run and return a sane time per round trip: speed is judged in the benchmark.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import pytest

from tests.peers import missing_peer

BENCHMARK = Path(__file__).resolve().parents[2] / "benchmarks" / "xmodem.py"


@pytest.fixture(scope="module")
def bench() -> ModuleType:
    spec = importlib.util.spec_from_file_location("bench_xmodem", BENCHMARK)
    assert spec is not None
    assert spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up by name
    spec.loader.exec_module(module)
    return module


def test_python_floor_times_a_round_trip(bench: ModuleType) -> None:
    trip = bench.pty_floor(133, rounds=200)
    assert 0 < trip < 0.05


def test_c_floor_compiles_and_times_a_round_trip(bench: ModuleType, tmp_path: Path) -> None:
    if bench.c_compiler() is None:
        missing_peer("a C compiler (cc or gcc) for the pty floor")
    program = bench.c_floor_program(tmp_path)
    assert program is not None
    for frame in (132, 1029):
        assert 0 < bench.c_floor(program, frame, rounds=200) < 0.05


def test_c_floor_reports_a_failure_instead_of_a_time(
    bench: ModuleType, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    if bench.c_compiler() is None:
        missing_peer("a C compiler (cc or gcc) for the pty floor")
    program = bench.c_floor_program(tmp_path)
    assert program is not None
    assert bench.c_floor(program, 5000, rounds=1) is None  # frame over the 4096-byte buffer
    assert bench.c_floor(program, 132, rounds=0) is None
    assert "failed, status 2" in capsys.readouterr().out
