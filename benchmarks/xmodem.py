"""Benchmark: XModem throughput and line efficiency, opendnc vs lrzsz vs PyPI ``xmodem``.

Every endpoint runs in its own process with its end of the link as stdin/stdout (lrzsz's
convention; ours and PyPI's follow it), so no two endpoints share an interpreter.

1. Raw pty pair (no line timing): ours -> ours, sx -> ours (see the note on lrzsz below) and
   PyPI -> PyPI, in all three modes. Reported: payload MB/s and the ratios ours/sx>ours and
   ours/PyPI; then the floor, a protocol-free two-process Python ping-pong of one frame per
   trip on the same kind of pty, and the best ratio to PyPI that any Python pair could reach
   with it; then the same ping-pong compiled from C (when a C compiler is installed): the
   kernel's own cost per trip, which bounds the ratio of any implementation in any language.
2. Virtual cable (``opendnc sim cable``, the paced null modem, in a child process) at
   115200 8N1: payload efficiency against the ceiling of each mode (128/133, 128/134,
   1024/1030 of 11,520 B/s) for the same three pairs, two ways:
   - "whole": the marginal rate of a small and a large transfer (below);
   - "steady": the mean ACK-to-ACK cycle of the large transfer's full blocks, read from the
     cable's line monitor. It leaves out start-up and endings, whose noise (a Python start
     varies by tens of milliseconds) moves the whole figure by a point or more at 64 KiB,
     and it is the same yardstick for every implementation. A block cycle beyond the line
     time of block and ACK is both ends' turnaround plus the cable's own latency.
   A transfer ends when the receiver exits with the file: ``rx`` discards its final ACK with a
   TCIOFLUSH when the cable has not read it within about 2 ms, and ``sx`` then waits for an
   answer that never comes.

Throughput is *marginal*: each pair moves a small and a large file and the script divides the
extra bytes by the extra time. That cancels fixed costs that have nothing to do with the
line: process start-up, the start handshake, and ``rx``'s habit of answering EOT about a
second late. Medians over ``--repeat`` runs.

    .venv/bin/python benchmarks/xmodem.py                 # full run, a few minutes
    .venv/bin/python benchmarks/xmodem.py --quick         # smaller files, one repeat

Note on lrzsz over a raw pty: ``rx`` flushes its input right after every ACK, so a sender
that answers at memory speed loses blocks (rx waits 5 s, then NAKs). The sx -> rx pair stalls
at random and its marginal rate is noise (from 0 to hundreds of MB/s), so on the raw pty
lrzsz is measured as ``sx`` sending into our receiver ("sx>ours"): the ratio ours/sx>ours
compares the two senders in front of the same receiver. On the cable the line delay removes
the race and the pure lrzsz pair is measured.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import select
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import time
import tty
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, contextmanager
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MODES = ("checksum", "crc", "1k")
FRAME = {"checksum": (128, 132), "crc": (128, 133), "1k": (1024, 1029)}  # (payload, frame bytes)
# payload share of the line: a block and its one-byte ACK
BLOCK_SHARE = {mode: payload / (frame + 1) for mode, (payload, frame) in FRAME.items()}
SENDER_HEAD_START = 0.4  # let the sender open its port before the receiver asks for data
SENDER_GRACE = 5.0  # seconds the sender may take to finish after the receiver has exited


# -- endpoint mode: python benchmarks/xmodem.py --endpoint send|recv MODE FILE ---------------


def run_endpoint(action: str, mode_name: str, path: str) -> int:
    """One opendnc transfer over stdin/stdout; exit status 0 on success."""
    from opendnc.errors import DncError
    from opendnc.transport.fd import FdStream
    from opendnc.xmodem.driver import receive, send
    from opendnc.xmodem.framing import Mode

    tty.setraw(0)
    mode = Mode(mode_name)
    stream = FdStream(0, 1)
    try:
        if action == "send":
            send(stream, Path(path).read_bytes(), mode=mode)
        else:
            with open(path, "wb") as sink:
                receive(stream, sink, mode=mode)
    except DncError as exc:
        print(f"opendnc endpoint: {exc}", file=sys.stderr)
        return 1
    return 0


# -- pairs ------------------------------------------------------------------------------


def _ours(action: str, mode: str, path: Path) -> list[str]:
    return [sys.executable, str(Path(__file__).resolve()), "--endpoint", action, mode, str(path)]


def _pypi(action: str, mode: str, path: Path) -> list[str]:
    return [sys.executable, "-m", "tests.interop.xmodem_pypi_peer", action, mode, str(path)]


def _lrzsz(action: str, mode: str, path: Path) -> list[str]:
    # A file name relative to the endpoint's folder (the transfer's): Debian's lrzsz
    # 0.12.21-10+deb12u1 refuses an absolute path with "Security Violation".
    if action == "send":
        return ["sx", "-X", "-q", *(["-k"] if mode == "1k" else []), path.name]
    return ["rx", "-X", "-q", *(["-c"] if mode != "checksum" else []), path.name]


def _sx_to_ours(action: str, mode: str, path: Path) -> list[str]:
    return _lrzsz(action, mode, path) if action == "send" else _ours(action, mode, path)


PAIRS: dict[str, Callable[[str, str, Path], list[str]]] = {
    "opendnc": _ours,
    "lrzsz": _lrzsz,
    "pypi": _pypi,
    "sx>ours": _sx_to_ours,  # raw pty only: rx's flush race makes the sx -> rx pair stall
}


Link = Callable[[], AbstractContextManager[tuple[int, int]]]


def random_data(size: int) -> bytes:
    """Random bytes that do not end in SUB (it would be taken for padding)."""
    data = bytearray(os.urandom(size))
    if data[-1] == 0x1A:
        data[-1] = 0x41
    return bytes(data)


@dataclass
class Run:
    seconds: float
    ok: bool
    note: str = ""


@contextmanager
def raw_pty() -> Iterator[tuple[int, int]]:
    """(sender fd, receiver fd): a raw pty pair, master for the sender."""
    master, slave = os.openpty()
    tty.setraw(master)
    tty.setraw(slave)
    try:
        yield master, slave
    finally:
        for fd in (master, slave):
            os.close(fd)


class CableLink:
    """A fresh virtual cable per transfer (side A the sender's), with its line monitor kept.

    The monitor timestamps every ACK that crosses the cable, so :meth:`block_cycle` gives the
    steady time per block of the last transfer, free of process start-up and of the endings.
    """

    def __init__(self, baud: int, workdir: Path) -> None:
        self.baud = baud
        self.monitor = workdir / "line-monitor.txt"

    @contextmanager
    def __call__(self) -> Iterator[tuple[int, int]]:
        from opendnc.sim.cable import CableProcess

        with CableProcess(baud=self.baud, monitor=self.monitor) as line:
            fd_a = os.open(line.path_a, os.O_RDWR | os.O_NOCTTY)
            fd_b = os.open(line.path_b, os.O_RDWR | os.O_NOCTTY)
            tty.setraw(fd_a)
            tty.setraw(fd_b)
            try:
                yield fd_a, fd_b
            finally:
                os.close(fd_a)
                os.close(fd_b)

    def block_cycle(self, frame: int) -> float | None:
        """Mean seconds from one ACK to the next over the last transfer, per full block.

        Only gaps in which exactly one ``frame``-byte block crossed count: that leaves out the
        start, the EOT, a 1K sender's short tail blocks and retries, and keeps every ordinary
        slow turnaround.
        """
        from opendnc.sim.cable import read_monitor

        gaps: list[float] = []
        last_ack: float | None = None
        carried = 0  # bytes sent to the receiver since the last ACK
        for record in read_monitor(self.monitor):
            if record.direction == "a>b":
                carried += len(record.data)
            elif record.data == b"\x06":
                if last_ack is not None and carried == frame:
                    gaps.append(record.seconds - last_ack)
                last_ack, carried = record.seconds, 0
        return statistics.mean(gaps) if len(gaps) >= 10 else None


def transfer(link: Link, impl: str, mode: str, data: bytes, limit: float) -> Run:
    """Move ``data`` with one implementation on both ends; time from receiver start to exit."""
    make = PAIRS[impl]
    with tempfile.TemporaryDirectory() as tmp:
        src, dst = Path(tmp) / "src.bin", Path(tmp) / "dst.bin"
        src.write_bytes(data)
        # Every endpoint runs in the transfer's folder (lrzsz takes only relative names);
        # PYTHONPATH lets ``python -m tests.…`` find the checkout from there.
        env = {**os.environ, "PYTHONPATH": str(ROOT)}
        with link() as (fd_send, fd_recv):
            sender = subprocess.Popen(
                make("send", mode, src),
                stdin=fd_send,
                stdout=fd_send,
                stderr=subprocess.PIPE,
                cwd=tmp,
                env=env,
            )
            time.sleep(SENDER_HEAD_START)
            start = time.perf_counter()
            receiver = subprocess.Popen(
                make("recv", mode, dst),
                stdin=fd_recv,
                stdout=fd_recv,
                stderr=subprocess.PIPE,
                cwd=tmp,
                env=env,
            )
            note = ""
            try:
                receiver.wait(timeout=limit)
            except subprocess.TimeoutExpired:
                note = f"over the {limit:.0f} s limit"
            # The transfer ends when the receiver has the file: rx flushes its tty output
            # (TCIOFLUSH) 2 ms after its last ACK, which on a pty can discard that ACK before
            # the cable reads it, leaving sx waiting for an answer that never comes.
            elapsed = time.perf_counter() - start
            with contextlib.suppress(subprocess.TimeoutExpired):
                sender.wait(timeout=SENDER_GRACE)
            if impl != "lrzsz" and not note and sender.poll() != 0:
                # only sx has the excuse above; any other sender must finish cleanly
                note = f"sender did not finish cleanly (status {sender.poll()})"
            for proc in (sender, receiver):
                if proc.poll() is None:
                    proc.kill()
                    proc.wait(5)
                if proc.stderr is not None:
                    proc.stderr.close()
        got = dst.read_bytes() if dst.exists() else b""
    ok = not note and got.rstrip(b"\x1a") == data.rstrip(b"\x1a")
    if not ok and not note:
        note = f"copy differs ({len(got)} of {len(data)} bytes)"
    return Run(elapsed, ok, note)


Plan = dict[str, tuple[int, int, float]]  # impl -> (small bytes, large bytes, time limit)


@dataclass
class Measured:
    rate: float | None  # median marginal payload bytes/s
    note: str
    cycle: float | None = None  # median steady seconds per block (cable only)


def marginal(link: Link, mode: str, plan: Plan, repeat: int) -> dict[str, Measured]:
    """Median payload bytes/s of (large - small) bytes over their time difference, per impl.

    On the cable also the median steady block cycle of the large transfers. The
    implementations take turns within each repeat, so a burst of load on the machine hits all
    of them alike.
    """
    rates: dict[str, list[float]] = {impl: [] for impl in plan}
    cycles: dict[str, list[float]] = {impl: [] for impl in plan}
    notes: dict[str, set[str]] = {impl: set() for impl in plan}
    for _ in range(repeat):
        for impl, (small, large, limit) in plan.items():
            runs = [
                transfer(link, impl, mode, random_data(small), limit),
                transfer(link, impl, mode, random_data(large), limit),
            ]
            bad = [r.note for r in runs if not r.ok]
            notes[impl].update(bad)
            extra = runs[1].seconds - runs[0].seconds
            if not bad and extra > 0:
                rates[impl].append((large - small) / extra)
            # the large transfer's monitor is still there: read its steady block cycle
            cycle = None
            if runs[1].ok and isinstance(link, CableLink):
                cycle = link.block_cycle(FRAME[mode][1])
            if cycle is not None:
                cycles[impl].append(cycle)
    result: dict[str, Measured] = {}
    for impl in plan:
        note = "; ".join(sorted(notes[impl]))
        rate = statistics.median(rates[impl]) if rates[impl] else None
        cycle = statistics.median(cycles[impl]) if cycles[impl] else None
        empty = rate is None and cycle is None
        result[impl] = Measured(rate, note or ("no valid run" if empty else ""), cycle)
    return result


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--endpoint", nargs=3, metavar=("ACTION", "MODE", "FILE"))
    parser.add_argument("--quick", action="store_true", help="small files, one repeat")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--pty-mib", type=float, default=2.0, help="large file on the raw pty")
    parser.add_argument("--cable-kib", type=int, default=64, help="large file on the cable")
    parser.add_argument("--baud", type=int, default=115200)
    parser.add_argument("--only", choices=["pty", "cable"], help="run one part only")
    args = parser.parse_args()
    if args.endpoint:
        return run_endpoint(*args.endpoint)
    if args.quick:
        args.repeat, args.pty_mib, args.cable_kib = 1, 1.0, 32
    missing = [c for c in ("sx", "rx") if shutil.which(c) is None]
    impls = [i for i in ("opendnc", "lrzsz", "pypi") if not (i == "lrzsz" and missing)]
    if missing:
        print(f"lrzsz not installed ({', '.join(missing)} missing): skipped")

    if args.only != "cable":
        run_pty(args, impls)
    if args.only != "pty":
        run_cable(args, impls)
    return 0


def pty_floor(frame: int, rounds: int = 5000) -> float:
    """Seconds per round trip of the cheapest possible Python pair on a raw pty.

    Two processes, no protocol at all: one writes ``frame`` bytes and waits for one byte back,
    the other reads the frame and answers. Every Python XModem pair pays at least this per
    block, so PyPI's time per block divided by it bounds the ratio any Python sender and
    receiver can reach against PyPI.
    """
    with raw_pty() as (fd_a, fd_b):
        pid = os.fork()
        if pid == 0:  # the answering side
            try:
                for _ in range(rounds):
                    got = 0
                    while got < frame:
                        got += len(os.read(fd_b, 4096))
                    os.write(fd_b, b"\x06")
            finally:
                os._exit(0)
        block = os.urandom(frame)
        started = time.perf_counter()
        for _ in range(rounds):
            os.write(fd_a, block)
            if not select.select([fd_a], [], [], 5.0)[0]:
                os.kill(pid, signal.SIGKILL)
                raise SystemExit("pty floor: the answering process stopped")
            os.read(fd_a, 1)
        elapsed = time.perf_counter() - started
        os.waitpid(pid, 0)
    return elapsed / rounds


# The floor of part 1 in C: the same two-process ping-pong with nothing but blocking
# read/write, so what it measures is the pty and the scheduler, not a language.
C_PING_PONG = r"""
#include <pty.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/wait.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

static void make_raw(int fd) {
    struct termios t;
    tcgetattr(fd, &t);
    cfmakeraw(&t);
    tcsetattr(fd, TCSANOW, &t);
}

int main(int argc, char **argv) {
    if (argc != 3) return 2;
    int frame = atoi(argv[1]), rounds = atoi(argv[2]), a, b;
    static char buf[4096], block[4096];
    struct timespec t0, t1;
    if (frame <= 0 || frame > 4096 || rounds <= 0) return 2;
    if (openpty(&a, &b, NULL, NULL, NULL) != 0) return 2;
    make_raw(a);
    make_raw(b);
    memset(block, 0x55, sizeof block);
    pid_t pid = fork();
    if (pid < 0) return 2;
    if (pid == 0) {
        close(a); /* each side holds only its own end: if the other dies, reads fail */
        for (int i = 0; i < rounds; i++) {
            for (int got = 0; got < frame;) {
                ssize_t n = read(b, buf, sizeof buf);
                if (n <= 0) _exit(1);
                got += (int)n;
            }
            if (write(b, "\x06", 1) != 1) _exit(1);
        }
        _exit(0);
    }
    close(b);
    clock_gettime(CLOCK_MONOTONIC, &t0);
    for (int i = 0; i < rounds; i++) {
        if (write(a, block, frame) != frame || read(a, buf, 1) != 1) return 1;
    }
    clock_gettime(CLOCK_MONOTONIC, &t1);
    int status;
    waitpid(pid, &status, 0);
    printf("%.9f\n", ((t1.tv_sec - t0.tv_sec) + (t1.tv_nsec - t0.tv_nsec) * 1e-9) / rounds);
    return status == 0 ? 0 : 1;
}
"""


def c_compiler() -> str | None:
    """A C compiler that can build the ping-pong (it needs Linux's openpty), or None."""
    if not sys.platform.startswith("linux"):
        return None
    return shutil.which("cc") or shutil.which("gcc")


def c_floor_program(workdir: Path) -> Path | None:
    """Compile the C ping-pong into ``workdir``; None without a working C compiler."""
    compiler = c_compiler()
    if compiler is None:
        print("  (no C compiler)")
        return None
    source, program = workdir / "ping_pong.c", workdir / "ping_pong"
    source.write_text(C_PING_PONG)
    built = subprocess.run(
        [compiler, "-O2", "-o", str(program), str(source), "-lutil"],
        capture_output=True,
        text=True,
    )
    if built.returncode != 0:
        print(f"  (C floor not measured: {compiler} failed: {built.stderr.strip()[:200]})")
        return None
    return program


def c_floor(program: Path, frame: int, rounds: int = 20000) -> float | None:
    """Seconds per round trip of the C ping-pong on a raw pty; None (and a note) on failure."""
    try:
        done = subprocess.run(
            [str(program), str(frame), str(rounds)], capture_output=True, text=True, timeout=120
        )
    except subprocess.TimeoutExpired:
        print(f"  (C ping-pong of {frame} bytes: over the 120 s limit)")
        return None
    if done.returncode != 0:
        print(f"  (C ping-pong of {frame} bytes failed, status {done.returncode})")
        return None
    return float(done.stdout)


def run_pty(args: argparse.Namespace, impls: list[str]) -> None:
    """Part 1: raw pty pair."""
    pty_large = int(args.pty_mib * (1 << 20)) // 1024 * 1024
    print(
        f"== raw pty pair: marginal payload MB/s, {pty_large >> 10} KiB vs 64 KiB, "
        f"median of {args.repeat}"
    )
    # sx -> rx stalls on a raw pty (module notes); sx into our receiver measures lrzsz's sender
    impls = ["sx>ours" if impl == "lrzsz" else impl for impl in impls]
    pty_rates: dict[tuple[str, str], float | None] = {}
    for mode in MODES:
        plan: Plan = {impl: (64 * 1024, pty_large, 120.0) for impl in impls}
        for impl, measured in marginal(raw_pty, mode, plan, args.repeat).items():
            rate, note = measured.rate, measured.note
            pty_rates[(impl, mode)] = rate
            shown = f"{rate / 1e6:8.2f} MB/s" if rate else "       n/a"
            print(f"  {mode:8} {impl:8} {shown}  {note}", flush=True)
    for mode in MODES:
        ours = pty_rates.get(("opendnc", mode))
        parts = []
        for other in ("sx>ours", "pypi"):
            theirs = pty_rates.get((other, mode))
            if ours and theirs:
                parts.append(f"ours/{other} = {ours / theirs:5.1f}x")
        print(f"  {mode:8} " + "   ".join(parts))
    print("  floor: a protocol-free Python ping-pong on the same kind of pty, one frame per trip")
    print_floor(pty_floor, pty_rates, "for a Python pair")
    with tempfile.TemporaryDirectory() as tmp:
        program = c_floor_program(Path(tmp))
        if program is None:
            print("  the kernel floor (C ping-pong) is not measured")
            return
        print("  kernel floor: the same ping-pong in C (blocking read/write, no interpreter)")
        print_floor(lambda frame: c_floor(program, frame), pty_rates, "in any language")


def print_floor(
    trip_of: Callable[[int], float | None], pty_rates: dict[tuple[str, str], float | None], who: str
) -> None:
    """Per mode: the floor's time per block, and PyPI's time per block over it.

    That quotient is the most any pair bound by this floor could gain over PyPI.
    """
    for mode in MODES:
        payload, frame = FRAME[mode]
        trips = [t for t in (trip_of(frame) for _ in range(3)) if t is not None]
        if not trips:
            continue
        trip = statistics.median(trips)
        line = f"  {mode:8} {trip * 1e6:5.1f} µs per block = {payload / trip / 1e6:6.2f} MB/s"
        pypi = pty_rates.get(("pypi", mode))
        if pypi:
            line += f"; best possible ratio to PyPI {who}: {payload / trip / pypi:4.1f}x"
        print(line)


def run_cable(args: argparse.Namespace, impls: list[str]) -> None:
    """Part 2: the virtual cable at a real line rate."""
    line_rate = args.baud / 10
    large = args.cable_kib * 1024
    print(
        f"\n== virtual cable {args.baud} 8N1: payload rate vs ceiling, median of {args.repeat}\n"
        f"   whole: marginal over {args.cable_kib} KiB vs 4 KiB transfers\n"
        f"   steady: mean ACK-to-ACK block cycle of the {args.cable_kib} KiB transfer, "
        f"from the cable's line monitor\n"
        f"   µs lost: time per block beyond the line time of block + ACK (both turnarounds)"
    )
    # (impl, mode) -> (whole, steady) efficiency
    eff: dict[tuple[str, str], tuple[float | None, float | None]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        link = CableLink(args.baud, Path(tmp))
        for mode in MODES:
            payload, frame = FRAME[mode]
            ceiling = line_rate * BLOCK_SHARE[mode]
            ideal = (frame + 1) / line_rate  # seconds per block and its ACK
            plan = {impl: (4 * 1024, large, 60.0) for impl in impls}
            for impl, got in marginal(link, mode, plan, args.repeat).items():
                whole = got.rate / ceiling if got.rate else None
                steady = ideal / got.cycle if got.cycle else None
                eff[(impl, mode)] = (whole, steady)
                shown = []
                if got.rate is not None and whole is not None:
                    lost = (payload / got.rate - payload / ceiling) * 1e6
                    shown.append(f"whole {100 * whole:5.1f} % ({lost:4.0f} µs lost)")
                if got.cycle is not None and steady is not None:
                    lost = (got.cycle - ideal) * 1e6
                    shown.append(f"steady {100 * steady:5.2f} % ({lost:4.0f} µs lost)")
                text = "   ".join(shown) or "n/a"
                print(f"  {mode:8} {impl:8} {text}  {got.note}", flush=True)
    print(
        "\n  ceilings (B/s): "
        + ", ".join(f"{mode} {line_rate * BLOCK_SHARE[mode]:.0f}" for mode in MODES)
    )
    for mode in MODES:
        ours_whole, ours_steady = eff.get(("opendnc", mode), (None, None))
        lrz_whole, lrz_steady = eff.get(("lrzsz", mode), (None, None))
        verdict = []
        if ours_whole is not None and mode == "1k":
            verdict.append(f"1K >= 95 %: {'yes' if ours_whole >= 0.95 else 'NO'}")
        for name, ours, lrz in (
            ("whole", ours_whole, lrz_whole),
            ("steady", ours_steady, lrz_steady),
        ):
            if ours is not None and lrz is not None:
                verdict.append(f"{name} ours {100 * ours:.2f} % vs lrzsz {100 * lrz:.2f} %")
        print(f"  {mode:8} " + "; ".join(verdict))


if __name__ == "__main__":
    sys.exit(main())
