"""Soak: the fault probes of issue 15, repeated against the virtual controls for a bounded time.

Five patterns take turns until ``--seconds`` have passed (``--smoke``: one short round each):

* ``lsv2-fuzz``   raw clients send fuzzed LSV2 telegrams (random names, payloads, paths that try
                  to leave the root, absurd lengths) while a well-behaved client uploads,
                  downloads and compares, and quiet clients start downloading a large file and
                  go silent. Failures: a stall (no answer to a probe on an open connection), a
                  wrong file for the good client, a path escape, a simulator that died.
* ``cut-link``    get / put / backup through a proxy that cuts the TCP link after a random
                  number of bytes. Failure: a partial or temporary file left behind; silent:
                  a complete-looking file with wrong bytes.
* ``xmodem-*``    3 x a 20 kB program over the noisy virtual cable (1e-4 bit errors and drops) in
                  checksum, CRC and 1K mode, received with the NC text check. ``resent``
                  counts blocks that passed the checksum but not the text check (NAKed, sent
                  again), ``caught`` transfers it refused; silent: a completed receive with
                  wrong bytes, or a file left by a failed one.
* ``mdc-abuse``   one client floods Q500 and never reads, another connects and never reads;
                  a well-behaved client must still get answers within 10 s.
* ``serial-*``    serial LSV2 over the virtual cable at 1e-4 bit errors, NC text and binary
                  both ways (``benchmarks/soak_serial_lsv2.py``, which also runs alone).
                  ``caught``: a typed error; silent: success reported with wrong bytes.
* ``dprnt``       a DPRNT source sends good lines among garbage lines, over-long lines (5 kB,
                  sometimes 1 MiB) and a cut last line. Failure: a complete line lost; silent: a
                  fragment or cut line recorded as if it were a complete line.

Prints cases, failures, caught and silent corruptions per pattern, and the simulators' peak
memory (VmHWM of the TNC and Haas simulator processes; the cable runs in this process).

    .venv/bin/python benchmarks/soak.py                 # 180 s
    .venv/bin/python benchmarks/soak.py --seconds 600
    .venv/bin/python benchmarks/soak.py --smoke --json  # a few seconds, for tests/bench
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import random
import re
import resource
import shutil
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path

from opendnc.errors import DncError, ProgramTextError
from opendnc.haas.listen import DprntListener, JsonlSink, open_source
from opendnc.haas.mdc_client import MdcClient
from opendnc.lsv2 import Client
from opendnc.lsv2.backup import backup
from opendnc.lsv2.framing import Frame, TelegramFramer
from opendnc.sim.cable import VirtualCable
from opendnc.transport import SerialStream
from opendnc.xmodem.driver import send
from opendnc.xmodem.events import Event, Retry
from opendnc.xmodem.files import receive_file
from opendnc.xmodem.framing import Mode
from opendnc.xmodem.receiver import ReceiverConfig
from opendnc.xmodem.sender import SenderConfig

sys.path.insert(0, str(Path(__file__).parent))
from simproc import start_server
from soak_serial_lsv2 import pattern_serial_lsv2

# -- bookkeeping --------------------------------------------------------------------------


@dataclass
class Tally:
    """Outcome counters of one pattern (or one XModem mode)."""

    cases: int = 0
    failures: int = 0
    caught: int = 0  # damage refused with a typed error (XModem text check)
    repaired: int = 0  # blocks that passed the checksum but not the text check: sent again
    silent: int = 0  # wrong data that looked right
    notes: list[str] = field(default_factory=list)

    def fail(self, why: str) -> None:
        self.failures += 1
        self._note(f"failure: {why}")

    def corrupt(self, why: str) -> None:
        self.silent += 1
        self._note(f"silent: {why}")

    def _note(self, text: str) -> None:
        if len(self.notes) < 6 and text not in self.notes:
            self.notes.append(text[:200])


@dataclass
class Soak:
    """Everything the patterns share: the simulators, a work folder, the clock, the dice."""

    work: Path
    rng: random.Random
    smoke: bool
    deadline: float
    tnc_port: int = 0
    tnc_root: Path = Path()
    mdc_port: int = 0
    tallies: dict[str, Tally] = field(default_factory=dict)

    def tally(self, name: str) -> Tally:
        return self.tallies.setdefault(name, Tally())

    def time_left(self) -> float:
        return self.deadline - time.monotonic()


def vm_hwm(pid: int) -> int | None:
    """Peak resident memory of a process in bytes (Linux ``VmHWM``), or None."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return None
    found = re.search(r"VmHWM:\s+(\d+) kB", status)
    return int(found.group(1)) * 1024 if found else None


def leftovers(folder: Path, expected: set[str]) -> list[str]:
    """Names in ``folder`` (recursively) that are not in ``expected``: temp or partial files."""
    if not folder.exists():
        return []
    return sorted(
        str(p.relative_to(folder))
        for p in folder.rglob("*")
        if p.is_file() and str(p.relative_to(folder)) not in expected
    )


# -- LSV2: fuzz while a good client works ---------------------------------------------------

NAMES = [
    "A_LG", "A_LO", "R_VR", "R_PR", "R_DI", "R_DR", "R_FI", "R_FL", "C_FL", "S_FL", "T_OK",
    "T_FD", "T_BD", "C_DC", "C_DM", "C_DD", "C_FD", "C_FC", "C_FR", "R_RI", "C_CC", "R_MB",
    "R_ST", "C_ST", "R_CI", "C_EK", "R_DP", "Z_ZZ",
]  # fmt: skip
ESCAPES = [b"TNC:\\..\\..\\etc\\passwd", b"..\\..\\outside\\x.h", b"TNC:/../../outside/y.h",
           b"PLC:\\..\\TNC\\..\\..\\z", b"TNC:\\nc_prog\\" + b"A" * 300]  # fmt: skip


def fuzz_telegram(rng: random.Random) -> bytes:
    """One well-framed telegram with a random name and payload (sometimes an absurd length)."""
    roll = rng.random()
    if roll < 0.03:
        return struct.pack(">I4s", rng.choice([0xFFFFFFF0, 1 << 20, 70000]), b"S_FL") + b"junk"
    name = rng.choice(NAMES)
    if roll < 0.35:
        payload = rng.choice(ESCAPES) + b"\0" + bytes([rng.randrange(4)])
    elif roll < 0.6:
        payload = bytes([rng.randrange(256) for _ in range(rng.randrange(8))])
    else:
        payload = rng.randbytes(rng.randrange(600))
    return TelegramFramer.encode(Frame(name, payload))


class Raw:
    """A raw LSV2 peer: send bytes, wait for a telegram of a given name."""

    def __init__(self, port: int) -> None:
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=5)
        self.framer = TelegramFramer()

    def ask(self, telegram: bytes, until: tuple[str, ...], timeout: float = 5.0) -> str:
        """Send, then read until a telegram named in ``until``: its name, "closed", "stall"."""
        try:
            self.sock.sendall(telegram)
        except OSError:
            return "closed"  # the simulator dropped this connection: allowed after garbage
        limit = time.monotonic() + timeout
        while True:
            frame = self.framer.next_frame()
            if frame is not None:
                if frame.mnemonic in until:
                    return frame.mnemonic
                continue
            left = limit - time.monotonic()
            if left <= 0:
                return "stall"
            self.sock.settimeout(left)
            try:
                data = self.sock.recv(65536)
            except TimeoutError:
                return "stall"
            except OSError:
                return "closed"
            if not data:
                return "closed"
            self.framer.feed(data)

    def close(self) -> None:
        self.sock.close()


PROBE = TelegramFramer.encode(Frame("R_VR", b""))


def fuzz_client(soak: Soak, seed: int, count: int, tally: Tally, lock: threading.Lock) -> None:
    rng = random.Random(seed)
    raw: Raw | None = None
    for _ in range(count):
        try:
            if raw is None:
                raw = Raw(soak.tnc_port)
                if rng.random() < 0.7:
                    user = rng.choice([b"FILE\0", b"INSPECT\0"])
                    raw.ask(TelegramFramer.encode(Frame("A_LG", user)), ("T_OK", "T_ER"))
            with contextlib.suppress(OSError):
                raw.sock.sendall(fuzz_telegram(rng))
            answer = raw.ask(PROBE, ("S_VR", "T_ER"))
        except OSError as exc:  # only connecting can raise here: the simulator refused us
            answer = f"connect: {exc}"
        with lock:
            tally.cases += 1
            if answer == "stall":
                tally.fail("no answer to R_VR after a fuzzed telegram (stall)")
            elif answer.startswith("connect"):
                tally.fail(answer)
        if answer in ("closed", "stall") or answer.startswith("connect"):
            if raw is not None:
                raw.close()
            raw = None
    if raw is not None:
        raw.close()


def quiet_downloaders(soak: Soak, count: int) -> list[Raw]:
    """Connections that start downloading the big file, take one block, and go silent."""
    quiet = []
    for _ in range(count):
        raw = Raw(soak.tnc_port)
        raw.ask(TelegramFramer.encode(Frame("A_LG", b"FILE\0")), ("T_OK", "T_ER"))
        raw.ask(TelegramFramer.encode(Frame("R_FL", b"TNC:\\soak\\BIG.H\0\x01")), ("S_FL", "T_ER"))
        quiet.append(raw)
    return quiet


def pattern_lsv2_fuzz(soak: Soak) -> None:
    tally = soak.tally("lsv2-fuzz")
    good = soak.tally("lsv2-good-client")
    clients, per_client = (3, 15) if soak.smoke else (12, 60)
    quiet = quiet_downloaders(soak, 2 if soak.smoke else 10)
    lock = threading.Lock()
    threads = [
        threading.Thread(
            target=fuzz_client, args=(soak, soak.rng.randrange(1 << 30), per_client, tally, lock)
        )
        for _ in range(clients)
    ]
    for thread in threads:
        thread.start()
    payload = soak.rng.randbytes(8_000 if soak.smoke else 200_000)
    local = soak.work / "good.bin"
    back = soak.work / "good.back"
    local.write_bytes(payload)
    while any(t.is_alive() for t in threads):
        good.cases += 1
        try:
            with Client("127.0.0.1", soak.tnc_port, timeout=10) as tnc:
                tnc.upload(local, "TNC:/soak/GOOD.BIN", binary=True)
                tnc.download("TNC:/soak/GOOD.BIN", back, binary=True)
                tnc.delete_file("TNC:/soak/GOOD.BIN")
            if back.read_bytes() != payload:
                good.corrupt("the good client downloaded different bytes")
        except DncError as exc:
            good.fail(f"good client: {exc}")
    for thread in threads:
        thread.join()
    for raw in quiet:
        raw.close()
    partial = soak.tnc_root / ".partial"
    limit = time.monotonic() + 5
    while partial.exists() and any(partial.iterdir()) and time.monotonic() < limit:
        time.sleep(0.05)  # uploads of closed connections are dropped as the server notices
    if partial.exists() and any(partial.iterdir()):
        tally.fail(f"half-written uploads left: {sorted(os.listdir(partial))}")
    outside = soak.work / "outside"
    escaped = sorted(p.name for p in outside.iterdir()) if outside.exists() else []
    if escaped != ["sentinel"]:
        tally.corrupt(f"files appeared outside the TNC root: {escaped}")


# -- LSV2: cut links during get / put / backup -----------------------------------------------


class CuttingProxy:
    """Forwards one TCP connection to ``port`` and cuts it after ``budget`` bytes (both ways)."""

    def __init__(self, port: int, budget: int) -> None:
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.port = self.listener.getsockname()[1]
        self.upstream = port
        self.budget = budget
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        self.listener.settimeout(10)
        try:
            down, _ = self.listener.accept()
        except OSError:
            return
        up = socket.create_connection(("127.0.0.1", self.upstream))
        left = [self.budget]
        lock = threading.Lock()

        def pump(src: socket.socket, dst: socket.socket) -> None:
            try:
                while data := src.recv(65536):
                    with lock:
                        take = min(len(data), left[0])
                        left[0] -= take
                    if take:
                        dst.sendall(data[:take])
                    if take < len(data):
                        break
            except OSError:
                pass
            for s in (down, up):
                with contextlib.suppress(OSError):
                    s.shutdown(socket.SHUT_RDWR)

        other = threading.Thread(target=pump, args=(up, down), daemon=True)
        other.start()
        pump(down, up)
        other.join()
        down.close()
        up.close()

    def close(self) -> None:
        self.listener.close()
        self.thread.join(15)


def pattern_cut_link(soak: Soak) -> None:
    tally = soak.tally("cut-link")
    rng = soak.rng
    sizes = [rng.randrange(1_000, 30_000 if soak.smoke else 300_000) for _ in range(3)]
    sources = {f"CUT{i}.BIN": rng.randbytes(size) for i, size in enumerate(sizes)}
    with Client("127.0.0.1", soak.tnc_port, timeout=10) as tnc:
        with contextlib.suppress(DncError):
            tnc.make_dir("TNC:/soak/cut")
        for name, data in sources.items():
            path = soak.work / name
            path.write_bytes(data)
            tnc.upload(path, f"TNC:/soak/cut/{name}", binary=True)
    for op in ("get", "put", "backup"):
        tally.cases += 1
        proxy = CuttingProxy(soak.tnc_port, rng.randrange(50, sum(sizes) + 2_000))
        dest = soak.work / f"cut-{op}-{rng.randrange(1 << 30)}"
        dest.mkdir()
        name = rng.choice(sorted(sources))
        outcome = "ok"
        try:
            with Client("127.0.0.1", proxy.port, timeout=5) as link:
                if op == "get":
                    link.download(f"TNC:/soak/cut/{name}", dest / name, binary=True)
                elif op == "put":
                    link.upload(soak.work / name, "TNC:/soak/cut/PUT.BIN", binary=True)
                else:
                    backup(link, "TNC:/soak/cut", dest)
        except DncError:
            outcome = "cut"
        except Exception as exc:  # anything untyped is a finding
            tally.fail(f"{op}: untyped {type(exc).__name__}: {exc}")
        finally:
            proxy.close()
        if op == "put":
            check_put(soak, tally, sources[name])
            continue
        for path in dest.rglob("*"):
            if not path.is_file():
                continue
            if path.name not in sources:
                tally.fail(f"{op} ({outcome}) left {path.name}")
            elif path.read_bytes() != sources[path.name]:
                tally.corrupt(f"{op} ({outcome}) wrote a wrong {path.name}")
        shutil.rmtree(dest)


def check_put(soak: Soak, tally: Tally, data: bytes) -> None:
    """After a cut upload the target is absent or whole, and no partial file stays."""
    target = soak.tnc_root / "TNC" / "soak" / "cut" / "PUT.BIN"
    partial = soak.tnc_root / ".partial"
    limit = time.monotonic() + 5
    while any(partial.iterdir()) if partial.exists() else False:
        if time.monotonic() > limit:
            tally.fail(f"put: partial upload left in .partial: {sorted(os.listdir(partial))}")
            break
        time.sleep(0.05)
    if target.exists():
        if target.read_bytes() != data:
            tally.corrupt("put: a cut upload left a wrong file on the control")
        target.unlink()


# -- XModem over the noisy cable ---------------------------------------------------------------

BAUD = 1_000_000
FAST_RX = ReceiverConfig(
    start_timeout=10.0, start_interval=0.3, block_timeout=1.0, char_timeout=0.15,
    purge_quiet=0.05, idle_timeout=15.0,
)  # fmt: skip
# the sender waits longer for an ACK than the receiver for a block, as by default
FAST_TX = SenderConfig(start_timeout=10.0, ack_timeout=1.5, eot_timeout=0.3)


def nc_program(rng: random.Random, size: int) -> bytes:
    lines = ["%", f"O{rng.randrange(1, 99999):05d} (SOAK)", "G20 G90 G54", "T1 M06", "S1000 M03"]
    while sum(len(line) + 1 for line in lines) < size:
        lines.append(
            f"G01 X{rng.randrange(100)}.{rng.randrange(10)} Y{rng.randrange(40)}.25 "
            f"F{rng.randrange(10, 50)}."
        )
    return ("\n".join([*lines, "M30", "%"]) + "\n").encode()


def pattern_xmodem(soak: Soak, mode: Mode) -> None:
    for _ in range(1 if soak.smoke else 3):
        xmodem_case(soak, mode)


def xmodem_case(soak: Soak, mode: Mode) -> None:
    """One noisy-cable transfer of a fresh program with a fresh seed."""
    tally = soak.tally(f"xmodem-{mode.value}")
    tally.cases += 1
    data = nc_program(soak.rng, 4_000 if soak.smoke else 20_000)
    dest_dir = soak.work / f"xm-{soak.rng.randrange(1 << 30)}"
    dest_dir.mkdir()
    dest = dest_dir / "O1.nc"
    seed = soak.rng.randrange(1 << 30)
    got: list[object] = [None]
    with VirtualCable(baud=BAUD, noise=1e-4, drop=1e-4, seed=seed) as cable:
        tx = SerialStream(cable.path_a, BAUD, timeout=0.05)
        rx = SerialStream(cable.path_b, BAUD, timeout=0.05)

        def count(event: Event) -> None:
            if isinstance(event, Retry) and "not NC text" in event.reason:
                tally.repaired += 1

        def receiving() -> None:
            try:
                got[0] = receive_file(rx, dest, mode=mode, config=FAST_RX, on_event=count)
            except DncError as exc:
                got[0] = exc

        thread = threading.Thread(target=receiving)
        thread.start()
        with contextlib.suppress(DncError):
            send(tx, data, mode=mode, config=FAST_TX)
        thread.join(60)
        tx.close()
        rx.close()
    outcome = got[0]
    if thread.is_alive():
        tally.fail(f"receiver hung (seed {seed})")
    elif isinstance(outcome, ProgramTextError):
        tally.caught += 1
    elif isinstance(outcome, DncError):
        tally.fail(f"{type(outcome).__name__}: {outcome} (seed {seed})")
    elif dest.exists() and dest.read_bytes() != data:
        tally.corrupt(f"received a different program, both ends succeeded (seed {seed})")
    completed = outcome is not None and not isinstance(outcome, DncError)
    left = leftovers(dest_dir, {"O1.nc"} if completed else set())
    if left:
        tally.corrupt(f"a failed receive left {left} (seed {seed})")
    shutil.rmtree(dest_dir, ignore_errors=True)


# -- MDC: clients that never read ---------------------------------------------------------------


def pattern_mdc_abuse(soak: Soak) -> None:
    tally = soak.tally("mdc-abuse")
    tally.cases += 1
    flood = socket.create_connection(("127.0.0.1", soak.mdc_port), timeout=5)
    silent = socket.create_connection(("127.0.0.1", soak.mdc_port), timeout=5)
    for s in (flood, silent):
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    stop = threading.Event()

    def flooding() -> None:
        request = b"?Q500\r\n" * 512
        with contextlib.suppress(OSError):
            flood.settimeout(1.0)
            while not stop.is_set():
                with contextlib.suppress(TimeoutError):
                    flood.sendall(request)

    thread = threading.Thread(target=flooding, daemon=True)
    thread.start()
    time.sleep(0.5)
    started = time.monotonic()
    answered = 0
    last: str = ""
    # Both MDC slots are held by the abusers: the third client gets one when the simulator
    # drops a stalled connection (after its 5 s drain bound), so allow a few such windows.
    while time.monotonic() - started < 20 and answered < 3:
        try:
            with MdcClient("127.0.0.1", soak.mdc_port, timeout=2.0) as client:
                while answered < 3:
                    client.query(100)
                    answered += 1
        except DncError as exc:
            last = f"{type(exc).__name__}: {exc}"
            time.sleep(0.2)
    if answered < 3:
        tally.fail(f"a well-behaved MDC client got {answered}/3 answers in 20 s ({last})")
    stop.set()
    for s in (flood, silent):
        s.close()
    thread.join(5)


# -- DPRNT: garbage, over-long lines, a cut last line -------------------------------------------

INCOMPLETE_KEYS = ("partial", "cut", "truncated", "dropped", "incomplete")


def recorded_as_complete(record: dict[str, object]) -> bool:
    """Whether a JSONL record claims to be a complete line (how a cut line is marked is the
    listener's choice: a false ``complete`` or a true ``partial``/``cut``/... flag)."""
    if record.get("complete") is False:
        return False
    return not any(record.get(key) for key in INCOMPLETE_KEYS)


def pattern_dprnt(soak: Soak) -> None:
    tally = soak.tally("dprnt")
    tally.cases += 1
    rng = soak.rng
    goods = [f"GOOD {i} X{rng.randrange(100)}.{rng.randrange(1000):03d}" for i in range(40)]
    stream = bytearray()
    for good in goods:
        roll = rng.random()
        if roll < 0.25:
            stream += b"M" * rng.choice([5_000, 5_000, 70_000] + ([] if soak.smoke else [1 << 20]))
            stream += b"\r\n"
        elif roll < 0.5:
            junk = bytes(b for b in rng.randbytes(rng.randrange(1, 300)) if b not in (10, 13))
            stream += junk + b"\r\n"
        stream += good.encode() + b"\r\n"
    stream += b"CUT TAIL X1.5"  # the link drops in the middle of this line
    listener_out = soak.work / f"dprnt-{rng.randrange(1 << 30)}.jsonl"
    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]

    def serve() -> None:
        conn, _ = server.accept()
        with conn:
            view = memoryview(bytes(stream))
            while view:
                cut = rng.randrange(1, 9000)
                conn.sendall(view[:cut])
                view = view[cut:]
        server.close()

    sender = threading.Thread(target=serve, daemon=True)
    sender.start()
    sink = JsonlSink(listener_out)
    listener = DprntListener(f"tcp://127.0.0.1:{port}", [sink], opener=open_source)
    runner = threading.Thread(target=lambda: listener.run(max_connects=1), daemon=True)
    runner.start()
    runner.join(30)
    if runner.is_alive():
        listener.stop()
        runner.join(5)
        tally.fail("the DPRNT listener did not finish after the source closed")
    sink.close()
    records = [json.loads(line) for line in listener_out.read_text().splitlines() if line]
    complete = [str(r.get("line", "")) for r in records if recorded_as_complete(r)]
    missing = [g for g in goods if g not in complete]
    if missing:
        tally.fail(f"{len(missing)} of {len(goods)} complete lines lost (first: {missing[0]!r})")
    fragments = [line for line in complete if line and set(line) == {"M"}]
    if fragments:
        tally.corrupt(f"{len(fragments)} fragment(s) of an over-long line recorded as lines")
    if any(line.startswith("CUT TAIL") for line in complete):
        tally.corrupt("a line cut by the link drop was recorded as a complete line")
    listener_out.unlink()


# -- the run ------------------------------------------------------------------------------------


@contextlib.contextmanager
def haas_simulator(root: Path) -> Iterator[tuple[subprocess.Popen[str], int]]:
    command = [sys.executable, "-m", "opendnc.cli.main", "sim", "haas", "--root", str(root)]
    proc = subprocess.Popen(
        [*command, "--mdc-port", "0"], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True
    )
    try:
        assert proc.stdout is not None
        port = 0
        limit = time.monotonic() + 20
        while not port and time.monotonic() < limit:
            found = re.match(r"MDC [\d.]+:(\d+)", proc.stdout.readline())
            if found:
                port = int(found.group(1))
        if not port:
            raise SystemExit("virtual Haas did not start")
        yield proc, port
    finally:
        proc.terminate()
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.communicate(timeout=10)
        if proc.poll() is None:
            proc.kill()
            proc.communicate()


def run(seconds: float, smoke: bool, seed: int) -> dict[str, object]:
    started = time.monotonic()
    work = Path(tempfile.mkdtemp(prefix="opendnc-soak-"))
    soak = Soak(work, random.Random(seed), smoke, started + seconds)
    (work / "outside").mkdir()
    (work / "outside" / "sentinel").write_bytes(b"x")
    soak.tnc_root = work / "tnc-root"
    soak.tnc_root.mkdir()
    big = soak.tnc_root / "TNC" / "soak" / "BIG.H"
    big.parent.mkdir(parents=True)
    with big.open("wb") as out:
        block = os.urandom(1 << 20)
        for _ in range(2 if smoke else 32):
            out.write(block)
    tnc, soak.tnc_port = start_server(soak.tnc_root, profile="tnc640")
    memory: dict[str, int | None] = {}
    patterns: list[Callable[[Soak], None]] = [
        pattern_lsv2_fuzz,
        pattern_cut_link,
        lambda s: pattern_xmodem(s, Mode.CHECKSUM),
        lambda s: pattern_xmodem(s, Mode.CRC),
        lambda s: pattern_xmodem(s, Mode.ONE_K),
        pattern_mdc_abuse,
        pattern_dprnt,
        pattern_serial_lsv2,  # serial LSV2 at 1e-4 (benchmarks/soak_serial_lsv2.py)
    ]
    rounds = 0
    try:
        with haas_simulator(work / "haas-root") as (haas, soak.mdc_port):
            while True:
                for pattern in patterns:
                    pattern(soak)
                    if tnc.poll() is not None:
                        soak.tally("lsv2-fuzz").fail("the virtual TNC died")
                        raise SystemExit("the virtual TNC died")
                rounds += 1
                if smoke or soak.time_left() <= 0:
                    break
            memory["haas_sim_peak"] = vm_hwm(haas.pid)
        memory["tnc_sim_peak"] = vm_hwm(tnc.pid)
    finally:
        tnc.terminate()
        with contextlib.suppress(subprocess.TimeoutExpired):
            tnc.communicate(timeout=10)
        if tnc.poll() is None:
            tnc.kill()
            tnc.communicate()
        shutil.rmtree(work, ignore_errors=True)
    memory["soak_process_peak"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    return {
        "seconds": round(time.monotonic() - started, 1),
        "rounds": rounds,
        "seed": seed,
        "patterns": {name: asdict(t) for name, t in sorted(soak.tallies.items())},
        "memory": memory,
    }


def report(result: dict[str, object]) -> None:
    patterns = result["patterns"]
    assert isinstance(patterns, dict)
    print(f"soak: {result['seconds']} s, {result['rounds']} rounds, seed {result['seed']}")
    print(f"{'pattern':<18}{'cases':>8}{'failures':>10}{'caught':>8}{'resent':>8}{'silent':>8}")
    for name, t in patterns.items():
        counts = [t["cases"], t["failures"], t["caught"], t["repaired"], t["silent"]]
        cells = zip(counts, (8, 10, 8, 8, 8), strict=True)
        print(f"{name:<18}" + "".join(f"{c:>{w}}" for c, w in cells))
    total = {k: sum(t[k] for t in patterns.values()) for k in ("cases", "failures", "silent")}
    print(f"{'total':<18}{total['cases']:>8}{total['failures']:>10}{'':>16}{total['silent']:>8}")
    memory = result["memory"]
    assert isinstance(memory, dict)
    for name, value in memory.items():
        shown = "n/a" if value is None else f"{value / 2**20:.1f} MiB"
        print(f"{name}: {shown}")
    for name, t in patterns.items():
        for note in t["notes"]:
            print(f"  {name}: {note}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=180.0, help="how long to soak")
    parser.add_argument("--smoke", action="store_true", help="one short round of each pattern")
    parser.add_argument("--seed", type=int, default=1, help="seed of every random choice")
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    args = parser.parse_args()
    result = run(args.seconds, args.smoke, args.seed)
    if args.json:
        print(json.dumps(result))
    else:
        report(result)
    patterns = result["patterns"]
    assert isinstance(patterns, dict)
    sys.exit(1 if any(t["silent"] for t in patterns.values()) else 0)


if __name__ == "__main__":
    main()
