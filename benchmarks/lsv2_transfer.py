"""Benchmark: LSV2 file transfer speed, opendnc's Client vs pyLSV2, against the virtual TNC.

The simulator runs in its own process (``opendnc sim tnc --port 0``), so both clients meet
the same server cost. Each client moves one binary file (default 20 MiB) down and up at the
largest buffer the control offers, several times; the script prints the median MB/s per
client and direction, the ratio ours/pyLSV2, and the protocol ceiling of this link:
payload per telegram divided by the measured round trip of a one-telegram request.

    .venv/bin/python benchmarks/lsv2_transfer.py --size-mib 20 --repeat 3
"""

from __future__ import annotations

import argparse
import logging
import os
import re
import socket
import statistics
import struct
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from opendnc.lsv2 import Client

MB = 1_000_000


def start_server(root: Path) -> tuple[subprocess.Popen[str], int]:
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
        found = re.search(r"listening on [\d.]+:(\d+)", proc.stdout.readline())
        if found:
            return proc, int(found.group(1))
    proc.kill()
    raise SystemExit("simulator did not start")


CPU: dict[str, list[float]] = {}
"""Client CPU seconds per (client, direction) run, filled by :func:`timed`."""


def timed(action: Callable[[], object], key: str = "") -> float:
    """Wall seconds of ``action``; its CPU time (this process = the client) goes to CPU."""
    cpu = time.process_time()
    started = time.perf_counter()
    action()
    wall = time.perf_counter() - started
    if key:
        CPU.setdefault(key, []).append(time.process_time() - cpu)
    return wall


def bench_ours(
    port: int, local: Path, back: Path, remote: str, repeat: int
) -> dict[str, list[float]]:
    times: dict[str, list[float]] = {"down": [], "up": []}
    with Client("127.0.0.1", port, timeout=30) as tnc:
        assert tnc.buffer_size == 4096, tnc.buffer_size
        for _ in range(repeat):
            times["up"].append(timed(lambda: tnc.upload(local, remote, binary=True), "ours up"))
            times["down"].append(
                timed(lambda: tnc.download(remote, back, binary=True), "ours down")
            )
            if back.read_bytes() != local.read_bytes():
                raise SystemExit("opendnc: downloaded bytes differ")
    return times


def bench_pylsv2(
    port: int, local: Path, back: Path, remote: str, repeat: int
) -> dict[str, list[float]]:
    import pyLSV2  # the independent client from PyPI

    logging.getLogger("LSV2 Client").setLevel(logging.ERROR)
    times: dict[str, list[float]] = {"down": [], "up": []}
    con = pyLSV2.LSV2("127.0.0.1", port=port, timeout=30, safe_mode=True)
    con.connect()
    try:
        for _ in range(repeat):
            times["up"].append(
                timed(
                    lambda: con.send_file(local, remote, override_file=True, binary_mode=True),
                    "pylsv2 up",
                )
            )
            times["down"].append(
                timed(
                    lambda: con.recive_file(remote, back, override_file=True, binary_mode=True),
                    "pylsv2 down",
                )
            )
            if back.read_bytes() != local.read_bytes():
                raise SystemExit("pyLSV2: downloaded bytes differ")
    finally:
        con.disconnect()
    return times


def _telegram(name: bytes, payload: bytes = b"") -> bytes:
    return struct.pack(">I", len(payload)) + name + payload


def _answer(sock: socket.socket) -> tuple[bytes, int]:
    buf = b""
    while len(buf) < 8:
        buf += sock.recv(65536)
    (length,) = struct.unpack_from(">I", buf)
    while len(buf) < 8 + length:
        buf += sock.recv(65536)
    return buf[4:8], length


def bench_raw(port: int, data: bytes, repeat: int, tag: int = 0) -> dict[str, list[float]]:
    """Lower bound for any Python client: a bare socket loop that only frames telegrams
    (no parsing, no files, no checks). What it cannot beat is the server's turnaround."""
    sock = socket.create_connection(("127.0.0.1", port))
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    for start in (b"A_LG", b"INSPECT\0"), (b"A_LG", b"FILE\0"), (b"C_CC", b"\x00\x07"):
        sock.sendall(_telegram(*start))
        assert _answer(sock)[0] == b"T_OK"
    ok, chunk = _telegram(b"T_OK"), 4086
    blocks = [_telegram(b"S_FL", data[i : i + chunk]) for i in range(0, len(data), chunk)]
    times: dict[str, list[float]] = {"down": [], "up": []}
    for rep in range(repeat):
        path = f"TNC:\\raw{tag}_{rep}.bin\0".encode()
        started = time.perf_counter()
        sock.sendall(_telegram(b"C_FL", path + b"\x01"))
        assert _answer(sock)[0] == b"T_OK"
        for block in blocks:
            sock.sendall(block)
            _answer(sock)
        sock.sendall(_telegram(b"T_FD"))  # no secure send: the control stays silent
        times["up"].append(time.perf_counter() - started)
        started = time.perf_counter()
        sock.sendall(_telegram(b"R_FL", path + b"\x01"))
        got = 0
        while (answer := _answer(sock))[0] == b"S_FL":
            got += answer[1]
            sock.sendall(ok)
        times["down"].append(time.perf_counter() - started)
        assert got == len(data), got
    sock.close()
    return times


def round_trip(port: int, count: int) -> tuple[float, int]:
    """Median seconds of the cheapest request/answer pair (``R_ST`` -> ``S_ST``, 8 + 20
    bytes, no work on the control) over a bare socket, and the data bytes per ``S_FL``."""
    sock = socket.create_connection(("127.0.0.1", port))
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    sock.sendall(_telegram(b"A_LG", b"INSPECT\0"))
    assert _answer(sock)[0] == b"T_OK"
    request = _telegram(b"R_ST")
    samples = []
    for _ in range(count):
        started = time.perf_counter()
        sock.sendall(request)
        _answer(sock)
        samples.append(time.perf_counter() - started)
    sock.close()
    return statistics.median(samples), 4096 - 10


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size-mib", type=float, default=20.0)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--profile", action="store_true", help="cProfile our client once.")
    args = parser.parse_args()

    with tempfile.TemporaryDirectory(prefix="lsv2-bench-") as tmp:
        work = Path(tmp)
        local = work / "payload.bin"
        local.write_bytes(os.urandom(int(args.size_mib * 1024 * 1024)))
        size = local.stat().st_size
        proc, port = start_server(work / "root")
        try:
            rtt, chunk = round_trip(port, 2000)
            if args.profile:
                import cProfile
                import pstats

                with cProfile.Profile() as prof:
                    bench_ours(port, local, work / "p.bin", "TNC:\\prof.bin", 1)
                pstats.Stats(prof).sort_stats("cumulative").print_stats(25)
            # Interleave the clients repetition by repetition, so that load from other
            # processes on this machine hits all of them alike.
            ours: dict[str, list[float]] = {"down": [], "up": []}
            theirs: dict[str, list[float]] = {"down": [], "up": []}
            raw: dict[str, list[float]] = {"down": [], "up": []}
            data = local.read_bytes()
            for rep in range(args.repeat):
                runs = [
                    (ours, lambda: bench_ours(port, local, work / "o.bin", "TNC:\\o.bin", 1)),
                    (theirs, lambda: bench_pylsv2(port, local, work / "t.bin", "TNC:\\t.bin", 1)),
                    (raw, lambda rep=rep: bench_raw(port, data, 1, tag=rep)),
                ]
                for into, run in runs:
                    for direction, values in run().items():
                        into[direction].extend(values)
        finally:
            proc.terminate()
            proc.wait(10)

    print(f"file {size / MB:.1f} MB, {args.repeat} repetitions, 4096-byte telegrams, loopback")
    print(f"telegram round trip (R_ST, bare socket, median of 2000): {rtt * 1e6:.0f} µs")
    print(f"protocol ceiling: {chunk} B / {rtt * 1e6:.0f} µs = {chunk / rtt / MB:.1f} MB/s")
    for direction in ("down", "up"):
        a = size / statistics.median(ours[direction]) / MB
        b = size / statistics.median(theirs[direction]) / MB
        print(
            f"{direction:4}: opendnc {a:6.1f} MB/s   pyLSV2 {b:6.1f} MB/s   "
            f"ratio {a / b:4.2f}x   ({a / (chunk / rtt / MB) * 100:.0f}% of ceiling)"
        )
    for direction in ("down", "up"):
        a = size / statistics.median(ours[direction]) / MB
        r = size / statistics.median(raw[direction]) / MB
        b = size / statistics.median(theirs[direction]) / MB
        print(
            f"{direction:4}: bare socket loop {r:6.1f} MB/s (= {r / b:4.2f}x pyLSV2): "
            f"the best any client can do here; opendnc reaches {a / r * 100:.0f}% of it"
        )
    telegrams = size / chunk
    for key, values in CPU.items():
        per = statistics.median(values) / telegrams * 1e6
        print(f"client CPU {key:11}: {statistics.median(values):.3f} s ({per:.0f} µs per block)")


if __name__ == "__main__":
    main()
