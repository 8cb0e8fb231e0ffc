"""`opendnc check`: problem lines, the summary, exit status, JSON and machine checks."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from opendnc.errors import InputError
from opendnc.server.config.shop import parse_config

CLI = [sys.executable, "-m", "opendnc.cli.main", "check"]
DATA = Path(__file__).resolve().parents[1] / "data" / "nccheck"


def check(*args: str | Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [*CLI, *map(str, args)], capture_output=True, text=True, timeout=120, check=False
    )


def test_a_clean_program_exits_0_with_one_summary_line() -> None:
    done = check(DATA / "clean_haas.nc")
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert len(lines) == 1
    assert lines[0].startswith(f"{DATA / 'clean_haas.nc'}: 0 errors, 0 warnings; haas, 2 tools")


def test_an_error_prints_file_line_and_exits_1() -> None:
    path = DATA / "arc_radius_too_small.nc"
    done = check(path)
    assert done.returncode == 1
    first, summary = done.stdout.splitlines()
    assert first.startswith(f"{path}:8: error: arc radius R10 is too small")
    assert "1 error, 0 warnings" in summary


def test_a_warning_alone_exits_0() -> None:
    done = check(DATA / "call_not_in_library.nc")
    assert done.returncode == 0
    assert ":5: warning: calls O04321, which is not in the library" in done.stdout


def test_klartext_problems_name_the_block() -> None:
    done = check(DATA / "kt_missing_label.h")
    assert done.returncode == 1
    assert done.stdout.splitlines()[0].endswith(":8: error: label 7 is not defined (block 7)")


def test_json_has_problems_tools_extents_and_moves() -> None:
    done = check(DATA / "clean_klartext.h", "--json")
    assert done.returncode == 0
    result = json.loads(done.stdout)
    assert result["control"] == "heidenhain"
    assert [t["tool"] for t in result["tools"]] == ["1", "DRILL_D8"]
    assert result["stock"] == {"min": [0.0, 0.0, -20.0], "max": [100.0, 80.0, 0.0], "axis": "Z"}
    assert result["extents"]["Z"] == [-15.0, 100.0]
    arcs = [m for m in result["moves"] if m["kind"].startswith("arc")]
    # RND R5 rounds the corner at (0, 80) to the right, then C turns about CC X+100 Y+40
    assert (arcs[0]["line"], arcs[0]["kind"], arcs[0]["center"]) == (10, "arc_cw", [5, 75, -5])
    assert (arcs[1]["line"], arcs[1]["kind"], arcs[1]["center"]) == (13, "arc_cw", [100, 40, -5])
    assert arcs[0]["plane"] == "xy"


def test_the_control_can_be_forced() -> None:
    done = check(DATA / "clean_haas.nc", "--control", "heidenhain")
    assert done.returncode == 1
    assert "does not start with BEGIN PGM" in done.stdout


@pytest.mark.parametrize(
    "args",
    [
        ["--control", "okuma"],
        ["--machine", "vf2"],
        ["--config", "shop.toml"],
    ],
)
def test_usage_errors_exit_2(args: list[str]) -> None:
    done = check(DATA / "clean_haas.nc", *args)
    assert done.returncode == 2
    assert done.stderr.startswith("error: ")
    assert done.stdout == ""


def test_a_missing_file_is_a_usage_error() -> None:
    done = check(DATA / "no_such_program.nc")
    assert done.returncode == 2
    assert "cannot read" in done.stderr


SHOP = """
[[machines]]
name = "vf2"
kind = "haas_ngc"
host = "127.0.0.1"
travel = { x = [-30.0, 0.0], y = [-16.0, 0.0], z = [-20.0, 0.0], units = "inch" }
work_offsets = { G54 = { x = -25.0, y = -8.0, z = -12.0 } }

[[machines]]
name = "tnc"
kind = "lsv2"
host = "127.0.0.1"
"""


def test_machine_checks_from_the_configuration(tmp_path: Path) -> None:
    config = tmp_path / "shop.toml"
    config.write_text(SHOP, "utf-8")
    done = check(DATA / "travel_overrun.nc", "--machine", "vf2", "--config", config)
    assert done.returncode == 1
    assert ":8: error: X goes to -35 in machine coordinates" in done.stdout
    done = check(DATA / "clean_haas.nc", "--machine", "tnc", "--config", config)
    assert done.returncode == 1
    assert ":1: error: a haas program cannot run on tnc (heidenhain control)" in done.stdout
    done = check(DATA / "clean_klartext.h", "--machine", "tnc", "--config", config)
    assert done.returncode == 0
    done = check(DATA / "clean_haas.nc", "--machine", "nope", "--config", config)
    assert done.returncode == 2
    assert "no machine named 'nope'" in done.stderr


def test_travel_keys_in_the_configuration(tmp_path: Path) -> None:
    shop = parse_config(SHOP, base=tmp_path)
    envelope = shop.machine("vf2").envelope
    assert envelope is not None
    assert envelope.travel_map() == {"X": (-30.0, 0.0), "Y": (-16.0, 0.0), "Z": (-20.0, 0.0)}
    assert envelope.offsets_map() == {"G54": {"X": -25.0, "Y": -8.0, "Z": -12.0}}
    assert shop.machine("tnc").envelope is None


@pytest.mark.parametrize(
    ("line", "key"),
    [
        ("travel = { x = [0.0, -30.0] }", "machines[0].travel.x"),
        ("travel = { q = [0.0, 1.0] }", "machines[0].travel.q"),
        ('travel = { x = "wide" }', "machines[0].travel.x"),
        ('travel = { x = [-1.0, 0.0], units = "feet" }', "machines[0].travel.units"),
        ("work_offsets = { G99 = { x = 1.0 } }", "machines[0].work_offsets.G99"),
        ('work_offsets = { G54 = { x = "a" } }', "machines[0].work_offsets.G54.x"),
    ],
)
def test_bad_travel_keys_name_the_key(tmp_path: Path, line: str, key: str) -> None:
    text = f'[[machines]]\nname = "vf2"\nkind = "haas_ngc"\nhost = "127.0.0.1"\n{line}\n'
    with pytest.raises(InputError) as caught:
        parse_config(text, base=tmp_path)
    assert str(caught.value).startswith(f"{key}: ")


# --------------------------------------------------------------------------- what it reads


def run_in_process(*args: str | Path) -> tuple[int, str]:
    """The command in this process (cheaper than a subprocess): exit status and output."""
    from typer.testing import CliRunner

    from opendnc.cli.main import app

    done = CliRunner().invoke(app, ["check", *map(str, args)])
    return done.exit_code, done.output


def test_a_fifo_is_refused_at_once(tmp_path: Path) -> None:
    fifo = tmp_path / "program.nc"
    os.mkfifo(fifo)  # nobody writes: opening it for reading would block forever
    done = check(fifo)  # the subprocess's timeout fails the test if it blocks
    assert done.returncode == 2
    assert "is a FIFO, not a regular file" in done.stderr
    assert done.stdout == ""


def _one_gib_of_memory() -> None:
    import resource

    resource.setrlimit(resource.RLIMIT_AS, (1 << 30, 1 << 30))


def test_a_device_is_refused_rather_than_read_until_memory_runs_out() -> None:
    # a subprocess with 1 GiB of address space: reading /dev/zero ends in MemoryError, not in
    # the test run being killed
    done = subprocess.run(
        [*CLI, "/dev/zero"],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
        preexec_fn=_one_gib_of_memory,
    )
    assert done.returncode == 2, done.stderr[-300:]
    assert "is a device or other special file" in done.stderr


def test_the_only_error_on_the_last_block_fails_the_check(tmp_path: Path) -> None:
    # the file is streamed (no size limit any more, tests/unit/nccheck/test_streaming.py
    # shows its memory stays flat): its only error, on its last block, exits 1
    big = tmp_path / "O01000.nc"
    pairs = 20_000
    with big.open("wb") as out:
        out.write(b"%\nO01000\nG21 G90 T1 M06\nS1000 M03\nG01 Z-1. F300.\n")
        out.write(b"X1.5 Y2.5 Z-1.\nX2.5 Y1.5 Z-1.\n" * pairs)
        out.write(b"G01 X1. #0=1\nM30\n%\n")
    last = 5 + 2 * pairs + 1
    status, output = run_in_process(big)
    assert status == 1, output[-300:]
    assert f"{big}:{last}: error:" in output
    assert len([line for line in output.splitlines() if ": error:" in line]) == 1


@pytest.mark.parametrize("word", ["S", "F"])
def test_an_overflowing_number_is_an_error_also_in_json(tmp_path: Path, word: str) -> None:
    program = tmp_path / "O01000.nc"
    digits = "9" * 309  # float() of it is infinity
    program.write_text(f"%\nO01000\nG21 G90 G17\n{word}{digits} M03\nM30\n%\n", "ascii")
    status, output = run_in_process(program)
    assert status == 1
    assert f"{program}:4: error: number 999999999999... (309 digits) is out of range" in output
    status, output = run_in_process(program, "--json")
    assert status == 1
    problems = json.loads(output)["problems"]
    assert [(p["line"], p["severity"]) for p in problems] == [(4, "error")]


def test_rapid_rate_and_control_are_machine_keys(tmp_path: Path) -> None:
    from opendnc.nccheck import limits_for

    text = (
        '[[machines]]\nname = "st20"\nkind = "haas_ngc"\nhost = "127.0.0.1"\n'
        'rapid_rate = 400.0\ncontrol = "haas-lathe"\n'
    )
    limits = limits_for(parse_config(text, base=tmp_path).machine("st20"))
    assert (limits.rapid_rate, limits.dialect) == (400.0, "haas-lathe")
    # the rapid rate is what the time estimate takes: 100 units at 400 per minute is 15 s
    from opendnc.nccheck import check_text

    program = "%\nO01000\nG21\nG00 X0. Y0. Z0.\nG00 Z100.\nM30\n%\n"
    assert check_text(program, machine=limits).cycle_time_s == pytest.approx(15.0)


@pytest.mark.parametrize(
    ("line", "key"),
    [
        ('control = "okuma"', "machines[0].control"),
        ("rapid_rate = 0", "machines[0].rapid_rate"),
        ('rapid_rate = "fast"', "machines[0].rapid_rate"),
    ],
)
def test_bad_check_keys_name_the_key(tmp_path: Path, line: str, key: str) -> None:
    text = f'[[machines]]\nname = "vf2"\nkind = "haas_ngc"\nhost = "127.0.0.1"\n{line}\n'
    with pytest.raises(InputError) as caught:
        parse_config(text, base=tmp_path)
    assert str(caught.value).startswith(f"{key}: ")


def test_the_control_option_takes_a_dialect() -> None:
    path = Path(__file__).resolve().parents[1] / "data" / "nccheck" / "corpus" / "gcode"
    status, output = run_in_process(path / "fanuc_lathe.nc", "--control", "fanuc-lathe")
    assert status == 0
    assert "; fanuc-lathe, 4 tools" in output
    status, output = run_in_process(path / "fanuc_lathe.nc", "--control", "haas-mill")
    assert status == 1
    assert "G96 is not a G code of the Haas mill control" in output
