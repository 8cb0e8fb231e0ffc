"""Benchmark: many concurrent LSV2 clients listing and transferring against the virtual TNC.

The simulator runs in its own process (``opendnc sim tnc --port 0``); the clients are pyLSV2
instances (the independent PyPI client), one thread each, spread over ``--processes`` client
processes so that the clients' own GIL does not dominate the measured latency.  Every
client connects, then repeats rounds of: list the program folder, upload a file, download it,
compare, delete.  Prints p50/p90/p99/max latency per operation kind and overall throughput.

    .venv/bin/python benchmarks/tnc_concurrency.py --clients 100 --rounds 5 --size 20000 \
        --processes 4
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import tempfile
import threading
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from simproc import start_server


def percentile(values: list[float], q: float) -> float:
    """Nearest-rank percentile."""
    ordered = sorted(values)
    index = min(len(ordered) - 1, max(0, round(q / 100 * len(ordered) + 0.5) - 1))
    return ordered[index]


KINDS = ("connect", "list", "upload", "download")


def run_clients(
    port: int, ids: list[int], rounds: int, size: int, work: Path, start_at: float
) -> tuple[dict[str, list[float]], list[str], int]:
    """One client process: a thread per client id; returns latencies, failures, bytes moved."""
    import logging

    import pyLSV2  # the independent client

    logging.getLogger("pyLSV2").setLevel(logging.CRITICAL)
    lock = threading.Lock()
    samples: dict[str, list[float]] = {k: [] for k in KINDS}
    failures: list[str] = []
    moved = [0]

    def client(n: int) -> None:
        local = work / f"c{n}.bin"
        back = work / f"c{n}.back"
        payload = os.urandom(size)
        local.write_bytes(payload)
        mine: dict[str, list[float]] = {k: [] for k in KINDS}
        try:
            time.sleep(max(0.0, start_at - time.time()))
            t0 = time.perf_counter()
            con = pyLSV2.LSV2("127.0.0.1", port=port, timeout=60, safe_mode=False)
            con.connect()
            mine["connect"].append(time.perf_counter() - t0)
            for r in range(rounds):
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
        except Exception as exc:
            with lock:
                failures.append(f"client {n}: {exc!r}")
            return
        with lock:
            for key, values in mine.items():
                samples[key].extend(values)
            moved[0] += 2 * size * rounds

    threads = [threading.Thread(target=client, args=(i,)) for i in ids]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return samples, failures, moved[0]


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--clients", type=int, default=100)
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--size", type=int, default=20000, help="bytes per uploaded file")
    parser.add_argument("--profile", default="tnc640")
    parser.add_argument("--processes", type=int, default=4, help="client processes")
    parser.add_argument("--port", type=int, default=0, help="use a simulator already running")
    args = parser.parse_args()

    work = Path(tempfile.mkdtemp(prefix="tnc-bench-"))
    proc: subprocess.Popen[str] | None = None
    if args.port:
        port = args.port
    else:
        proc, port = start_server(work / "root", profile=args.profile)
    groups = [list(range(i, args.clients, args.processes)) for i in range(args.processes)]
    start_at = time.time() + 2.0  # every client starts at the same moment
    samples: dict[str, list[float]] = {k: [] for k in KINDS}
    failures: list[str] = []
    moved = 0
    try:
        with ProcessPoolExecutor(args.processes) as pool:
            futures = [
                pool.submit(run_clients, port, g, args.rounds, args.size, work, start_at)
                for g in groups
                if g
            ]
            for fut in futures:
                part, bad, count = fut.result()
                for key, values in part.items():
                    samples[key].extend(values)
                failures.extend(bad)
                moved += count
    finally:
        if proc is not None:
            proc.terminate()
            proc.wait(10)
    elapsed = time.time() - start_at

    print(
        f"virtual TNC ({args.profile}): {args.clients} concurrent pyLSV2 clients in "
        f"{args.processes} processes, {args.rounds} rounds each, {args.size} B files, "
        f"wall {elapsed:.2f} s"
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
        f"throughput: {ops / elapsed:.0f} operations/s, {moved / elapsed / 1e6:.2f} MB/s "
        f"payload (upload + download)"
    )
    print(f"failures: {len(failures)}")
    for line in failures[:10]:
        print("  " + line)
    if failures:
        raise SystemExit(1)


if __name__ == "__main__":
    main()
