"""Benchmark: many concurrent LSV2 clients listing and transferring against the virtual TNC.

The simulator runs in its own process (``opendnc sim tnc --port 0``); the clients are pyLSV2
instances (the independent PyPI client), one thread each.  Every client connects, then repeats
rounds of: list the program folder, upload a file, download it, compare, delete.  Prints
p50/p90/p99/max latency per operation kind and overall throughput.

    .venv/bin/python benchmarks/tnc_concurrency.py --clients 100 --rounds 5 --size 20000
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path


def start_server(profile: str, root: Path) -> tuple[subprocess.Popen[str], int]:
    """Run the simulator CLI in a child process and read back its port."""
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "opendnc.cli.main",
            "sim",
            "tnc",
            "--port",
            "0",
            "--profile",
            profile,
            "--root",
            str(root),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    assert proc.stdout is not None
    deadline = time.monotonic() + 20
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        found = re.search(r"listening on [\d.]+:(\d+)", line)
        if found:
            return proc, int(found.group(1))
    proc.kill()
    raise SystemExit("simulator did not start")


def percentile(values: list[float], q: float) -> float:
    """Nearest-rank percentile."""
    ordered = sorted(values)
    index = min(len(ordered) - 1, max(0, round(q / 100 * len(ordered) + 0.5) - 1))
    return ordered[index]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--clients", type=int, default=100)
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--size", type=int, default=20000, help="bytes per uploaded file")
    parser.add_argument("--profile", default="tnc640")
    args = parser.parse_args()

    import logging

    import pyLSV2  # the independent client

    logging.getLogger("pyLSV2").setLevel(logging.CRITICAL)
    work = Path(tempfile.mkdtemp(prefix="tnc-bench-"))
    proc, port = start_server(args.profile, work / "root")
    lock = threading.Lock()
    samples: dict[str, list[float]] = {"connect": [], "list": [], "upload": [], "download": []}
    failures: list[str] = []
    moved = [0]
    barrier = threading.Barrier(args.clients)

    def client(n: int) -> None:
        local = work / f"c{n}.bin"
        back = work / f"c{n}.back"
        payload = os.urandom(args.size)
        local.write_bytes(payload)
        try:
            barrier.wait(60)
            t0 = time.perf_counter()
            con = pyLSV2.LSV2("127.0.0.1", port=port, timeout=60, safe_mode=False)
            con.connect()
            mine = {"connect": [time.perf_counter() - t0], "list": [], "upload": [], "download": []}
            for r in range(args.rounds):
                remote = f"TNC:\\nc_prog\\bench_{n}_{r}.bin"
                t = time.perf_counter()
                con.change_directory("TNC:\\nc_prog")
                con.directory_content()
                mine["list"].append(time.perf_counter() - t)
                t = time.perf_counter()
                ok = con.send_file(local, remote, override_file=True, binary_mode=True)
                mine["upload"].append(time.perf_counter() - t)
                t = time.perf_counter()
                ok = ok and con.recive_file(remote, back, override_file=True, binary_mode=True)
                mine["download"].append(time.perf_counter() - t)
                if not ok or back.read_bytes() != payload:
                    raise RuntimeError(f"client {n} round {r}: transfer mismatch")
                con.delete_file(remote)
            con.disconnect()
            with lock:
                for key, values in mine.items():
                    samples[key].extend(values)
                moved[0] += 2 * args.size * args.rounds
        except Exception as exc:
            with lock:
                failures.append(f"client {n}: {exc!r}")

    threads = [threading.Thread(target=client, args=(i,)) for i in range(args.clients)]
    start = time.perf_counter()
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    elapsed = time.perf_counter() - start
    proc.terminate()
    proc.wait(10)

    print(
        f"virtual TNC ({args.profile}): {args.clients} concurrent pyLSV2 clients, "
        f"{args.rounds} rounds each, {args.size} B files, wall {elapsed:.2f} s"
    )
    print(f"{'operation':<10} {'n':>6} {'p50 ms':>9} {'p90 ms':>9} {'p99 ms':>9} {'max ms':>9}")
    for key, values in samples.items():
        if values:
            print(
                f"{key:<10} {len(values):>6} {statistics.median(values) * 1e3:>9.1f} "
                f"{percentile(values, 90) * 1e3:>9.1f} {percentile(values, 99) * 1e3:>9.1f} "
                f"{max(values) * 1e3:>9.1f}"
            )
    ops = sum(len(v) for v in samples.values())
    print(
        f"throughput: {ops / elapsed:.0f} operations/s, {moved[0] / elapsed / 1e6:.2f} MB/s "
        f"payload (upload + download)"
    )
    print(f"failures: {len(failures)}")
    for line in failures[:10]:
        print("  " + line)
    if failures:
        raise SystemExit(1)


if __name__ == "__main__":
    main()
