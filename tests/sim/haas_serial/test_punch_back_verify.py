"""Issue 20, item 6: a load that checksum XModem calls good but the control stores damaged is
found by punching it back (`xmodem send --verify`, `haas verify`).

The virtual Haas (side A of a virtual cable) stores what it received, damage included, as a
real one would, and with ``punch_back`` punches each program out again, as the operator does
for the check. The noisy run uses a seed whose noise lets one block through with two bit
errors that cancel in the 8-bit sum (found and replayed by :mod:`.silent_damage`).
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from opendnc.sim.cable import VirtualCable
from opendnc.sim.haas import HaasConfig, SimHaasThread, SimOptions
from opendnc.sim.haas.serial_front import (
    Selection,
    SerialFrontEnd,
    SerialMode,
    SerialOptions,
    start_serial,
)

from .silent_damage import BER, program, silent_damage

CLI = [sys.executable, "-m", "opendnc.cli.main"]
SEED = 157  # F20. becomes "F2 ." on line 163, with a +16 elsewhere in the block


def run(*args: str, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "COLUMNS": "400"}  # one line per message
    return subprocess.run(
        [*CLI, *args], capture_output=True, text=True, timeout=timeout, env=env, check=False
    )


@contextmanager
def haas_on_cable(
    root: Path, *, noise: float = 0.0, seed: int | None = None, mode: str = "receive"
) -> Iterator[tuple[str, SerialFrontEnd]]:
    """The virtual Haas on side A, punching back what it receives; yields the PC's port."""
    options = SerialOptions(
        baud=115200, mode=Selection(SerialMode(mode)), punch_back=mode == "receive"
    )
    with (
        VirtualCable(baud=115200, noise=noise, seed=seed) as cable,
        SimHaasThread(HaasConfig(), root, SimOptions(mdc_port=0)) as thread,
    ):
        sim = thread.sim
        assert sim is not None

        async def attach() -> SerialFrontEnd:
            front = await start_serial(sim, cable.path_a, 115200, None, options)
            sim.add_front_end(front)
            return front

        yield cable.path_b, thread._submit(attach())


def test_model_seed_gives_one_cancelling_double_flip() -> None:
    damage = silent_damage(SEED)
    assert damage is not None
    sent = program()
    assert len(damage.stored) == len(sent)
    changed = [i for i in range(len(sent)) if sent[i] != damage.stored[i]]
    assert len(changed) == 2  # two bytes, one block
    assert changed[1] - changed[0] < 128
    # the 8-bit sum of the block cannot see it
    assert (
        sum(sent[changed[0] : changed[1] + 1]) % 256
        == sum(damage.stored[changed[0] : changed[1] + 1]) % 256
    )


def test_clean_line_verifies(tmp_path: Path) -> None:
    source = tmp_path / "O01000.nc"
    source.write_bytes(program())
    with haas_on_cable(tmp_path / "mem") as (pc, front):
        done = run("xmodem", "send", str(source), "--port", pc, "--baud", "115200", "--verify")
        assert done.returncode == 0, done.stderr
        assert "verified: O01000 on the control matches O01000.nc (307 lines)" in done.stdout
        assert front.programs == [1000]


def test_silent_damage_passes_xmodem_and_is_caught_by_the_punch_back(tmp_path: Path) -> None:
    damage = silent_damage(SEED)
    assert damage is not None
    sent = program()
    sent_line = sent.split(b"\n")[damage.line].decode()
    stored_line = damage.stored.split(b"\n")[damage.line].decode()
    source = tmp_path / "O01000.nc"
    source.write_bytes(sent)
    memory = tmp_path / "mem"
    started = time.monotonic()
    with haas_on_cable(memory, noise=BER, seed=SEED) as (pc, front):
        done = run("xmodem", "send", str(source), "--port", pc, "--baud", "115200", "--verify")
        # XModem itself called the load good: every block was acknowledged
        assert "sent O01000" in done.stdout, done.stderr
        assert done.returncode == 1, done.stdout + done.stderr
        assert (
            f"error: O01000 on the control differs at line {damage.line}: "
            f"sent {sent_line!r}, punched {stored_line!r}"
        ) in done.stderr
        assert "verified" not in done.stdout
        # load and punch; the control notes the punch's end once its last byte is out, which
        # on a loaded machine can be after the PC has read it and exited (seen at -n 12)
        deadline = time.monotonic() + 10
        while len(front.messages) < 2 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert front.messages[:2] == ["RS232 DONE", "RS232 DONE"]
    # the control kept the damaged program, as a real one does
    kept = (memory / "O01000.nc").read_bytes().split(b"\n")
    assert kept[damage.line].decode() == stored_line
    assert kept[damage.line] != sent.split(b"\n")[damage.line]
    assert time.monotonic() - started < 60


def test_haas_verify_reports_a_program_that_differs(tmp_path: Path) -> None:
    """`haas verify` alone: the operator punches O01000 and the PC holds another version."""
    memory = tmp_path / "mem"
    memory.mkdir()
    (memory / "O01000.nc").write_bytes(program())
    edited = tmp_path / "O01000.nc"
    edited.write_bytes(program().replace(b"G01 X-1.0037", b"G01 X-1.0038", 1))
    assert edited.read_bytes() != program()
    with haas_on_cable(memory, mode="idle") as (pc, front):
        front.select("punch:O1000")
        done = run("haas", "verify", str(edited), "--port", pc, "--baud", "115200", "--json")
    assert done.returncode == 1
    line = program().split(b"\n").index(b"G01 X-1.0037 Y1.0091 F20.")
    assert f"differs at line {line}: sent 'G01 X-1.0038 Y1.0091 F20.'" in done.stderr
    assert done.stdout == ""
