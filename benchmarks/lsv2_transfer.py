"""Benchmark: LSV2 file transfer speed, opendnc's Client vs pyLSV2, against the virtual TNC.

The simulator runs in its own process (``opendnc sim tnc --port 0``), so all clients meet
the same server cost. Each client moves one binary file (default 20 MiB) up and down at the
largest buffer the control offers; the clients take turns, in a rotating order, once per
repetition. The script prints every run's MB/s, the medians, the ratio ours/pyLSV2 (median
of the per-repetition ratios and ratio of the medians), the ceiling of this link (payload per
telegram divided by the round trip of a bare-socket client that only frames telegrams), the
CPU time per block of each client and of the simulator, and the host's load average.

Transfers are stop-and-wait (one round trip per 4 KiB block), so every block costs the
simulator's turnaround plus the client's and, without pinning, a cross-CPU wake-up whose
cost varies run to run on a 2-CPU VM; ``--pin same`` removes that noise by putting clients
and simulator on one CPU.

    .venv/bin/python benchmarks/lsv2_transfer.py --size-mib 20 --repeat 7 [--pin same]
        [--sim-loop asyncio]
"""

from __future__ import annotations

import argparse
import importlib.util
import logging
import os
import socket
import statistics
import struct
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from opendnc.lsv2 import Client
from simproc import start_server

MB = 1_000_000

BUFFERS: dict[str, int] = {}
"""Telegram buffer each client negotiated with the simulator."""

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
        BUFFERS["opendnc"] = tnc.buffer_size
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
    BUFFERS["pyLSV2"] = con._llcom._buffer_size
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
        cpu = time.process_time()
        started = time.perf_counter()
        sock.sendall(_telegram(b"C_FL", path + b"\x01"))
        assert _answer(sock)[0] == b"T_OK"
        for block in blocks:
            sock.sendall(block)
            _answer(sock)
        sock.sendall(_telegram(b"T_FD"))  # no secure send: the control stays silent
        times["up"].append(time.perf_counter() - started)
        CPU.setdefault("bare up", []).append(time.process_time() - cpu)
        cpu = time.process_time()
        started = time.perf_counter()
        sock.sendall(_telegram(b"R_FL", path + b"\x01"))
        got = 0
        while (answer := _answer(sock))[0] == b"S_FL":
            got += answer[1]
            sock.sendall(ok)
        times["down"].append(time.perf_counter() - started)
        CPU.setdefault("bare down", []).append(time.process_time() - cpu)
        assert got == len(data), got
    sock.close()
    return times


def server_cpu(pid: int) -> float:
    """CPU seconds (user + system) the simulator process has used so far (Linux /proc)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return float("nan")
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size-mib", type=float, default=20.0)
    parser.add_argument("--repeat", type=int, default=7)
    parser.add_argument(
        "--tnc-profile",
        default="tnc320",
        help="Simulator profile. The default, tnc320, answers R_PR with the system parameters"
        " captured from a real TNC 320 (max block length 4088).",
    )
    parser.add_argument("--profile", action="store_true", help="cProfile our client once.")
    parser.add_argument(
        "--pin",
        choices=("none", "same", "split"),
        default="none",
        help="CPU affinity of clients and simulator: 'same' puts both on CPU 0 (round trip ="
        " sum of their CPU costs, no cross-CPU wake-ups), 'split' puts them on CPUs 0 and 1.",
    )
    parser.add_argument(
        "--sim-loop",
        choices=("auto", "asyncio"),
        default="auto",
        help="Event loop of the simulator: 'auto' = uvloop when installed (opendnc[sim]),"
        " 'asyncio' = the standard loop.",
    )
    args = parser.parse_args()
    sim_loop = args.sim_loop
    if sim_loop == "auto":
        sim_loop = "uvloop" if importlib.util.find_spec("uvloop") else "asyncio"

    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory(prefix="lsv2-bench-") as tmp:
        work = Path(tmp)
        local = work / "payload.bin"
        local.write_bytes(os.urandom(int(args.size_mib * 1024 * 1024)))
        size = local.stat().st_size
        proc, port = start_server(work / "root", profile=args.tnc_profile, loop=args.sim_loop)
        if args.pin != "none":
            os.sched_setaffinity(0, {0})
            os.sched_setaffinity(proc.pid, {0} if args.pin == "same" else {1})
        try:
            if args.profile:
                import cProfile
                import pstats

                with cProfile.Profile() as prof:
                    bench_ours(port, local, work / "p.bin", "TNC:\\prof.bin", 1)
                pstats.Stats(prof).sort_stats("cumulative").print_stats(25)
            data = local.read_bytes()
            clients: dict[str, Callable[[int], dict[str, list[float]]]] = {
                "opendnc": lambda rep: bench_ours(port, local, work / "o.bin", "TNC:\\o.bin", 1),
                "pyLSV2": lambda rep: bench_pylsv2(port, local, work / "t.bin", "TNC:\\t.bin", 1),
                "bare": lambda rep: bench_raw(port, data, 1, tag=rep),
            }
            wall: dict[str, dict[str, list[float]]] = {n: {"down": [], "up": []} for n in clients}
            serv: dict[str, list[float]] = {name: [] for name in clients}
            names = list(clients)
            bench_ours(port, local, work / "w.bin", "TNC:\\w.bin", 1)  # warm-up, not counted
            CPU.clear()
            for rep in range(args.repeat):
                # Rotate the order every repetition, so that neither client always runs first
                # and load from other processes on this machine hits all of them alike.
                for name in names[rep % 3 :] + names[: rep % 3]:
                    before = server_cpu(proc.pid)
                    for direction, values in clients[name](rep).items():
                        wall[name][direction].extend(values)
                    serv[name].append(server_cpu(proc.pid) - before)
        finally:
            proc.terminate()
            proc.wait(10)
    load_after = os.getloadavg()

    blocks = size / 4086
    mbs = {n: {d: [size / t / MB for t in v] for d, v in w.items()} for n, w in wall.items()}
    print(
        f"file {size / MB:.1f} MB = {blocks:.0f} blocks of 4086 B (4096-byte telegrams), "
        f"loopback, {args.repeat} repetitions, clients interleaved, CPU pinning: {args.pin}, "
        f"simulator loop: {sim_loop}"
    )
    print(
        f"simulator profile {args.tnc_profile}; negotiated telegram buffers: "
        + ", ".join(f"{name} {size} B" for name, size in BUFFERS.items())
        + " (pyLSV2 reads max_block_length as the whole telegram, we read it as the payload)"
    )
    print(
        f"host: {os.cpu_count()} CPUs, load average {load_before[0]:.2f} before, "
        f"{load_after[0]:.2f} after (other processes skew single runs: read medians)"
    )
    for direction in ("down", "up"):
        print(f"{direction}:")
        for name in names:
            runs = " ".join(f"{v:5.1f}" for v in mbs[name][direction])
            print(
                f"  {name:8} median {statistics.median(mbs[name][direction]):6.1f} MB/s  [{runs}]"
            )
    print("ratio opendnc / pyLSV2 (median of per-repetition ratios; ratio of medians):")
    ok = True
    for direction in ("down", "up"):
        paired = [
            a / b for a, b in zip(mbs["opendnc"][direction], mbs["pyLSV2"][direction], strict=True)
        ]
        of_medians = statistics.median(mbs["opendnc"][direction]) / statistics.median(
            mbs["pyLSV2"][direction]
        )
        ok &= of_medians >= 1.5
        print(
            f"  {direction:4} {statistics.median(paired):4.2f}x; {of_medians:4.2f}x  "
            f"(per repetition: {' '.join(f'{r:4.2f}' for r in paired)})"
        )
    rtt = {d: size / (statistics.median(mbs["bare"][d]) * MB) / blocks for d in ("down", "up")}
    for direction in ("down", "up"):
        ceiling = 4086 / rtt[direction] / MB
        ours = statistics.median(mbs["opendnc"][direction])
        print(
            f"ceiling {direction:4}: 4086 B / {rtt[direction] * 1e6:.0f} µs round trip of a "
            f"bare-socket client = {ceiling:.1f} MB/s; opendnc reaches {ours / ceiling:.0%}"
        )
    for key, values in CPU.items():
        per = statistics.median(values) / blocks * 1e6
        print(f"client CPU {key:11}: {statistics.median(values):.3f} s ({per:.0f} µs per block)")
    for name in names:
        per = statistics.median(serv[name]) / (2 * blocks) * 1e6
        print(f"simulator CPU serving {name:8}: {per:.0f} µs per block (both directions)")
    print("goal (issue #2): >= 1.5x both ways:", "met" if ok else "NOT met")


if __name__ == "__main__":
    main()
