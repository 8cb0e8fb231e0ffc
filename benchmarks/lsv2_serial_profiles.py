"""Long run: 1 MiB binary and NC-text files up and down over serial LSV2, per control profile.

Setup as in the issue: ``opendnc sim cable`` (own process) at 57600 baud, 11 bits a character
(8E1), the virtual TNC of ``--profile`` on one end, our client on the other with 256-byte
telegrams (``--max-buffer``). Each file goes up (then is read back over TCP and compared) and
down again, and must be byte-identical. At 57600 8E1 a 1 MiB file takes about 4 minutes each
way, so one profile takes about 16 minutes: this is run by hand (numbers in
docs/lsv2-serial.md), the test suite moves smaller files (tests/sim/test_lsv2_serial_cable.py).

    .venv/bin/python benchmarks/lsv2_serial_profiles.py --profile itnc530 [--size-kib 1024]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

from opendnc.lsv2 import Client
from opendnc.lsv2.serial_stream import SerialLine
from opendnc.sim.cable import CableProcess
from opendnc.sim.tnc import start_tnc
from opendnc.sim.tnc.serial_front import attach_serial


def nc_program(size: int) -> bytes:
    """Conversational NC text of about ``size`` bytes (CR LF line ends)."""
    lines = [b"0 BEGIN PGM BIG MM"]
    total, n = 0, 1
    while total < size - 40:
        line = b"%d L X+%d.%03d Y-%d.5 R0 F%d" % (n, n % 500, n % 1000, n % 77, 100 + n)
        lines.append(line)
        total += len(line) + 2
        n += 1
    lines.append(b"%d END PGM BIG MM" % n)
    return b"\r\n".join(lines) + b"\r\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--profile", default="itnc530")
    parser.add_argument("--size-kib", type=int, default=1024)
    parser.add_argument("--baud", type=int, default=57600)
    parser.add_argument(
        "--max-buffer", type=int, default=256, help="telegram size cap (4096: what the CLI asks)"
    )
    args = parser.parse_args()
    size = args.size_kib * 1024
    files = {
        "BIG.bin": (os.urandom(size - 3) + b"\x10\x10\x03", True),
        "BIG.H": (nc_program(size), False),
    }
    print(f"profile {args.profile}, {args.baud} baud 8E1, telegrams up to {args.max_buffer} bytes")
    with (
        tempfile.TemporaryDirectory() as tmp,
        CableProcess(baud=args.baud, bits_per_char=11) as cable,
        start_tnc(args.profile, root=Path(tmp) / "tnc") as tnc,
    ):
        work = Path(tmp)
        attach_serial(tnc, cable.path_a, baud=args.baud)
        line = SerialLine(cable.path_b, args.baud)
        for name, (data, binary) in files.items():
            (work / name).write_bytes(data)
            kind = "binary" if binary else "ASCII"
            with Client.over_serial(line, max_buffer=args.max_buffer, timeout=30) as client:
                started = time.perf_counter()
                client.upload(work / name, f"TNC:/{name}", binary=binary)
                up = time.perf_counter() - started
            with Client("127.0.0.1", tnc.port) as tcp:
                tcp.download(f"TNC:/{name}", work / f"tcp-{name}", binary=binary)
            assert (work / f"tcp-{name}").read_bytes() == data, f"{kind} upload differs"
            with Client.over_serial(line, max_buffer=args.max_buffer, timeout=30) as client:
                buffer = client.buffer_size
                started = time.perf_counter()
                client.download(f"TNC:/{name}", work / f"back-{name}", binary=binary)
                down = time.perf_counter() - started
            assert (work / f"back-{name}").read_bytes() == data, f"{kind} download differs"
            print(
                f"{kind} {len(data):,} bytes: put {up:.1f} s ({len(data) / up:.0f} B/s), "
                f"get {down:.1f} s ({len(data) / down:.0f} B/s), byte-identical, "
                f"{buffer}-byte telegrams"
            )
        stats = cable.close()
    print(f"cable: {stats}")


if __name__ == "__main__":
    main()
