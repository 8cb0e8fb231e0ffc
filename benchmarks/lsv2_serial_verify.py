"""What the end-to-end check of a serial text upload costs (docs/lsv2-serial.md, "Every text
upload verified").

Over a clean virtual cable (8E1, 256-byte telegrams) an NC program goes up N times; the client
times each upload (which includes the check) and, separately, the check's own ``R_FI`` round
trip, and prints both and their ratio.

    .venv/bin/python benchmarks/lsv2_serial_verify.py --baud 57600 --size 20000
"""

from __future__ import annotations

import argparse
import statistics
import time

from opendnc.lsv2 import Client
from opendnc.lsv2.serial_stream import SerialLine
from opendnc.sim.cable import CableProcess
from opendnc.sim.tnc import start_tnc
from opendnc.sim.tnc.serial_front import attach_serial


def program(size: int) -> bytes:
    lines = [b"0 BEGIN PGM V MM"]
    while sum(len(x) + 2 for x in lines) < size:
        n = len(lines)
        lines.append(b"%d L X+%d.125 Y-%d.5 FMAX" % (n, n % 400, n % 77))
    return b"\r\n".join(lines) + b"\r\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--baud", type=int, default=57600)
    parser.add_argument("--size", type=int, default=20_000, help="bytes of NC text")
    parser.add_argument("--runs", type=int, default=5)
    args = parser.parse_args()
    data = program(args.size)
    uploads: list[float] = []
    checks: list[float] = []
    with (
        CableProcess(baud=args.baud, bits_per_char=11) as cable,
        start_tnc("tnc320") as tnc,
    ):
        attach_serial(tnc, cable.path_a, baud=args.baud)
        line = SerialLine(cable.path_b, args.baud, telegram_size=256)
        with Client.over_serial(line, timeout=30) as client:
            for run in range(args.runs):
                remote = f"TNC:/V{run}.H"
                started = time.perf_counter()
                client.write_file(remote, data, binary=False)
                uploads.append(time.perf_counter() - started)
                started = time.perf_counter()
                client.file_info(remote)  # what the check adds: one R_FI round trip
                checks.append(time.perf_counter() - started)
            assert client.serial_checks == args.runs
            assert client.serial_readbacks == 0
    upload, check = statistics.median(uploads), statistics.median(checks)
    print(f"{len(data)} bytes of NC text at {args.baud} 8E1, 256-byte telegrams, {args.runs} runs")
    print(f"upload with its check: median {upload:.2f} s; the check (R_FI): {check * 1000:.0f} ms")
    print(f"the check costs {100 * check / (upload - check):.1f} % of the upload")


if __name__ == "__main__":
    main()
