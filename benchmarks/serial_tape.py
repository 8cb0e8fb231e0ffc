"""Benchmark: tape send and drip-feed against the line's character ceiling.

The PC side (``opendnc.tape.serial_io.send_program``, fanuc-0i profile: ISO 7E2, sent as
8N2 with the parity in the data, 8-byte writes so that little follows a DC3) sends a program
to the virtual Fanuc over the virtual cable, which runs in its own process
(``opendnc sim cable``, 11 bits per character) with its line monitor on. Two operations:

* ``send``: the control in READ (EDIT mode), which starts the transfer with DC1;
* ``dnc``: the control in TAPE mode, running blocks as fast as they come (a control whose
  blocks are short moves), so nothing but our own writing can leave the line idle.

The rate is read from the cable's monitor on the control's side: the bytes delivered after
the first delivery, divided by the time from the first delivery to the last. That is the
line's steady rate as the control saw it, without the start handshake and the PC's process
and port start-up. The ceiling is ``baud / 11`` characters per second; the target is 95 %.

    .venv/bin/python benchmarks/serial_tape.py            # 9600 and 115200 baud, about 2 minutes
    .venv/bin/python benchmarks/serial_tape.py --quick    # smaller programs
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from opendnc.sim.cable import CableProcess, read_monitor  # noqa: E402
from opendnc.sim.fanuc import FanucOptions, Mode, Selection, VirtualFanuc  # noqa: E402
from opendnc.tape.profiles import get_profile  # noqa: E402
from opendnc.tape.serial_io import open_tape_port, send_program  # noqa: E402

BITS = 11  # 7E2 / 8N2


def program(path: Path, size: int) -> int:
    """A program of about ``size`` bytes; returns its block count."""
    lines = ["%", "O0001 (BENCH)", "G21", "T1 M06", "G54", "S1000 M03"]
    i = 0
    while sum(len(line) + 1 for line in lines) < size:
        lines.append(f"G01 X{i % 97}.125 Y{i % 13}.5 Z-0.{i % 9}5 F250.")
        i += 1
    lines += ["M30", "%"]
    path.write_text("\n".join(lines) + "\n")
    return len(lines)


def measure(baud: int, op: str, size: int, folder: Path) -> tuple[float, float, float]:
    """(rate in characters/s at the control, ceiling, seconds of the PC's call)."""
    profile = get_profile("fanuc-0i").with_changes(baud=baud)
    source = folder / "O0001.nc"
    program(source, size)
    monitor = folder / f"line-{baud}-{op}.txt"
    mode = Selection(Mode.TAPE if op == "dnc" else Mode.READ)
    options = FanucOptions(block_rate=0.0, buffer_blocks=64, resume_blocks=16)
    with CableProcess(baud=baud, bits_per_char=BITS, monitor=monitor) as cable:
        pc = open_tape_port(cable.path_b, profile)
        try:
            with VirtualFanuc(
                cable.path_a,
                folder / f"mem-{baud}-{op}",
                profile=profile,
                options=options,
                mode=mode,
            ):
                started = time.monotonic()
                send_program(pc, source, profile, drip_feed=op == "dnc", safe_mode=False)
                took = time.monotonic() - started
                time.sleep(0.3)
        finally:
            pc.close()
    records = [r for r in read_monitor(monitor) if r.direction == "b>a"]
    first, last = records[0], records[-1]
    carried = sum(len(r.data) for r in records) - len(first.data)
    rate = carried / (last.seconds - first.seconds)
    return rate, baud / BITS, took


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="smaller programs")
    args = parser.parse_args()
    # full sizes exceed the 10-15 kB the cable and the ptys hold, so the PC is held to the line
    sizes = {9600: 3_000 if args.quick else 24_000, 115200: 30_000 if args.quick else 200_000}
    print(f"{'baud':>7} {'op':>5} {'bytes':>7} {'chars/s':>9} {'ceiling':>9} {'share':>7}  PC call")
    worst = 1.0
    with tempfile.TemporaryDirectory() as tmp:
        for baud, size in sizes.items():
            for op in ("send", "dnc"):
                rate, ceiling, took = measure(baud, op, size, Path(tmp))
                share = rate / ceiling
                worst = min(worst, share)
                print(
                    f"{baud:>7} {op:>5} {size:>7} {rate:>9.1f} {ceiling:>9.1f} {share:>7.1%}"
                    f"  {took:.2f} s"
                )
    print(f"lowest share of the ceiling: {worst:.1%} (target 95 %)")


if __name__ == "__main__":
    main()
