"""Benchmark: serial LSV2 payload throughput against the line ceiling (docs/lsv2-serial.md).

Setup: ``opendnc sim cable`` (own process) at 57600 baud, 11 bits a character (8E1), the
virtual TNC 320 serving serial LSV2 on one end (``opendnc sim tnc --serial … --no-tcp``, own
process), our blocking client on the other end with 256-byte telegrams (``max_buffer=256``:
246 payload bytes per ``S_FL``). One binary file goes up, then down.

Ceiling: the line time of every character the protocol needs per file block (docs/lsv2-serial.md,
"Line ceiling"): the sender's ENQ, frame (DLE STX, name, payload with every 0x10 doubled,
DLE ETX, BCC) and EOT, the receiver's DLE 0 and DLE 1, and the whole ``T_OK`` transmission of
the answer (15 characters), i.e. ``payload + stuffed + 30`` characters per block, counted for
the actual file. The script prints the ceiling, our rate and the ratio (target ≥ 90 %).

    .venv/bin/python benchmarks/lsv2_serial.py [--size-kib 1024] [--baud 57600]

The default size (128 KiB, about 30 s each way) keeps a run short; ``--size-kib 1024`` is the
1 MiB transfer of the issue (about 4 minutes each way).
"""

from __future__ import annotations

import argparse
import os
import selectors
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from opendnc.lsv2 import Client
from opendnc.lsv2.serial_stream import SerialLine
from opendnc.sim.cable import CableProcess

BUFFER = 256
DATA_LIMIT = BUFFER - 10  # payload bytes per S_FL (ops.base.SessionState.data_limit)
OK_TRANSMISSION = 15  # ENQ, DLE 0, DLE STX T_OK DLE ETX BCC, DLE 1, EOT


def ceiling_chars(data: bytes) -> int:
    """Characters on the line for all file blocks of ``data`` (both directions)."""
    total = 0
    for start in range(0, len(data), DATA_LIMIT):
        block = data[start : start + DATA_LIMIT]
        frame = 2 + 4 + len(block) + block.count(0x10) + 2 + 1
        total += 1 + frame + 1 + 2 + 2 + OK_TRANSMISSION
    return total


def start_sim(path: str, root: Path, baud: int) -> subprocess.Popen[str]:
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "opendnc.cli.main",
            "sim",
            "tnc",
            "--profile",
            "tnc320",
            "--root",
            str(root),
            "--serial",
            path,
            "--baud",
            str(baud),
            "--no-tcp",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "COLUMNS": "200"},
    )
    assert proc.stdout is not None
    with selectors.DefaultSelector() as sel:
        sel.register(proc.stdout, selectors.EVENT_READ)
        if not sel.select(timeout=30):
            proc.kill()
            raise SystemExit("virtual TNC did not start")
    proc.stdout.readline()
    return proc


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size-kib", type=int, default=128)
    parser.add_argument("--baud", type=int, default=57600)
    args = parser.parse_args()
    data = os.urandom(args.size_kib * 1024)
    char_time = 11 / args.baud
    ceiling = len(data) / (ceiling_chars(data) * char_time)
    print(f"line: {args.baud} baud 8E1 = {args.baud / 11:.1f} characters/s each way")
    print(f"telegrams: {BUFFER} bytes, {DATA_LIMIT} payload bytes per S_FL")
    print(f"ceiling: {ceiling:.1f} B/s for this {len(data):,}-byte file")
    with (
        tempfile.TemporaryDirectory() as tmp,
        CableProcess(baud=args.baud, bits_per_char=11) as cable,
    ):
        work = Path(tmp)
        sim = start_sim(cable.path_a, work / "tnc", args.baud)
        try:
            (work / "up.bin").write_bytes(data)
            line = SerialLine(cable.path_b, args.baud)
            with Client.over_serial(line, max_buffer=BUFFER, timeout=30) as tnc:
                assert tnc.buffer_size == BUFFER
                started = time.perf_counter()
                tnc.upload(work / "up.bin", "TNC:/bench.bin", binary=True)
                up = time.perf_counter() - started
                started = time.perf_counter()
                tnc.download("TNC:/bench.bin", work / "down.bin", binary=True)
                down = time.perf_counter() - started
            assert (work / "down.bin").read_bytes() == data, "download differs"
        finally:
            sim.send_signal(signal.SIGTERM)
            sim.wait(10)
    for name, seconds in (("upload", up), ("download", down)):
        rate = len(data) / seconds
        print(
            f"{name}: {seconds:.1f} s, {rate:.1f} B/s, "
            f"{100 * rate / ceiling:.1f} % of the ceiling (target >= 90 %)"
        )


if __name__ == "__main__":
    main()
