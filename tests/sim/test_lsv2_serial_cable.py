"""`opendnc lsv2 --serial` through `opendnc sim cable` at 57600 baud 8E1 (11 bits a character).

Every command's answer over the serial line must equal the same command's answer over TCP
from the same virtual control, and files must travel both ways byte-identical. The cable runs
in its own process at real line speed (5236 characters/s): the suite moves 8 KiB (tnc320) and
4 KiB files, and 48 KiB at 460800 baud; the 1 MiB transfers of the issue (about 4 minutes each
way) are run by hand with benchmarks/lsv2_serial_profiles.py (docs/lsv2-serial.md).
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from opendnc.sim.cable import CableProcess
from opendnc.sim.tnc import TncHandle, start_tnc
from opendnc.sim.tnc.serial_front import attach_serial
from tests.sim.lsv2_cli import lsv2_ok, lsv2_over_tcp

SIZES = {"tnc320": 8192, "itnc530": 4096, "tnc426": 4096}


@dataclass
class Bench:
    tnc: TncHandle
    pc_end: str
    profile: str


@pytest.fixture(scope="module", params=sorted(SIZES))
def bench(
    request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[Bench]:
    profile = request.param
    with (
        CableProcess(baud=57600, bits_per_char=11) as cable,
        start_tnc(profile, root=tmp_path_factory.mktemp(profile)) as tnc,
    ):
        attach_serial(tnc, cable.path_a)
        yield Bench(tnc, cable.path_b, profile)


def over_serial(bench: Bench, *args: str) -> str:
    return lsv2_ok("--serial", bench.pc_end, "--timeout", "20", *args)


def over_tcp(bench: Bench, *args: str) -> str:
    return lsv2_over_tcp(bench.tnc, *args)


def test_info_json_matches_the_profile_and_tcp(bench: Bench) -> None:
    info = json.loads(over_serial(bench, "info", "--json"))
    profile = bench.tnc.profile
    assert info["control"] == profile.model
    assert info["nc_version"] == profile.nc_software
    tcp = json.loads(over_tcp(bench, "info", "--json"))
    # over serial the CLI asks for 256-byte telegrams unless --telegram-size says otherwise
    # (docs/lsv2-serial.md, "Telegram size"); over TCP for the most the control allows
    assert info.pop("buffer_size") == 256
    assert tcp.pop("buffer_size") >= 1024
    assert info == tcp


def test_ls_status_and_plc_read_match_tcp(bench: Bench) -> None:
    for args in (
        ("ls", "TNC:/", "--json"),
        ("status", "--json"),
        ("plc", "read", "W4", "2", "--json"),
    ):
        serial_out = json.loads(over_serial(bench, *args))
        assert serial_out == json.loads(over_tcp(bench, *args)), args


def nc_program(size: int) -> bytes:
    lines = [b"0 BEGIN PGM SER MM"]
    n = 1
    while sum(len(x) + 2 for x in lines) < size - 40:
        lines.append(b"%d L X+%d.%03d Y-%d.5 R0 F%d" % (n, n % 500, n % 1000, n % 77, 100 + n))
        n += 1
    lines.append(b"%d END PGM SER MM" % n)
    return b"\r\n".join(lines) + b"\r\n"


def test_put_and_get_binary_and_ascii_byte_identical(bench: Bench, tmp_path: Path) -> None:
    size = SIZES[bench.profile]
    binary = os.urandom(size - 3) + b"\x10\x10\x03"  # DLE stuffing at the end too
    ascii_ = nc_program(size)
    (tmp_path / "blob.bin").write_bytes(binary)
    (tmp_path / "SER.H").write_bytes(ascii_)
    over_serial(bench, "put", str(tmp_path / "blob.bin"), "TNC:/")
    over_serial(bench, "put", "--ascii", str(tmp_path / "SER.H"), "TNC:/SER.H")
    # what arrived on the control, read back over TCP
    over_tcp(bench, "get", "TNC:/blob.bin", str(tmp_path / "tcp.bin"))
    over_tcp(bench, "get", "--ascii", "TNC:/SER.H", str(tmp_path / "tcp.h"))
    assert (tmp_path / "tcp.bin").read_bytes() == binary
    assert (tmp_path / "tcp.h").read_bytes() == ascii_
    # and back over the serial line
    over_serial(bench, "get", "TNC:/blob.bin", str(tmp_path / "back.bin"))
    over_serial(bench, "get", "--ascii", "TNC:/SER.H", str(tmp_path / "back.h"))
    assert (tmp_path / "back.bin").read_bytes() == binary
    assert (tmp_path / "back.h").read_bytes() == ascii_


FAST = 460800
"""Baud rate of the larger transfers: 8x the issue's 57600, so 48 KiB take about a second."""


@pytest.mark.parametrize("profile", sorted(SIZES))
def test_larger_files_at_a_high_baud_rate_per_profile(profile: str, tmp_path: Path) -> None:
    """48 KiB binary and NC text both ways with the CLI's own telegram size, which each
    profile caps differently (tnc426 at 1024 bytes): the 1 MiB transfers of the issue at
    57600 baud take 4 minutes each way and are run by hand (benchmarks/lsv2_serial_profiles.py,
    numbers in docs/lsv2-serial.md)."""
    size = 48 * 1024
    binary = os.urandom(size - 3) + b"\x10\x10\x03"
    ascii_ = nc_program(size)
    (tmp_path / "big.bin").write_bytes(binary)
    (tmp_path / "BIG.H").write_bytes(ascii_)
    with (
        CableProcess(baud=FAST, bits_per_char=11) as cable,
        start_tnc(profile, root=tmp_path / "tnc") as tnc,
    ):
        attach_serial(tnc, cable.path_a, baud=FAST)
        bench = Bench(tnc, cable.path_b, profile)
        fast = ("--baud", str(FAST), "--telegram-size", "4096")
        over_serial(bench, *fast, "put", str(tmp_path / "big.bin"), "TNC:/")
        over_serial(bench, *fast, "put", "--ascii", str(tmp_path / "BIG.H"), "TNC:/BIG.H")
        assert (tnc.root / "TNC" / "big.bin").read_bytes() == binary
        over_tcp(bench, "get", "--ascii", "TNC:/BIG.H", str(tmp_path / "tcp.h"))
        assert (tmp_path / "tcp.h").read_bytes() == ascii_
        over_serial(bench, *fast, "get", "TNC:/big.bin", str(tmp_path / "back.bin"))
        over_serial(bench, *fast, "get", "--ascii", "TNC:/BIG.H", str(tmp_path / "back.h"))
    assert (tmp_path / "back.bin").read_bytes() == binary
    assert (tmp_path / "back.h").read_bytes() == ascii_
