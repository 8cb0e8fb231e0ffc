"""Soak: serial LSV2 at a bit-error rate of 1e-4 (issue 20, items 4 and 5).

Each round starts the virtual cable (115200 baud 8E1, 1e-4 bit errors, parity marked, a fresh
seed) and a virtual TNC 320 on one end, and moves four files with our blocking client and
256-byte telegrams: NC text up, binary up, NC text down, binary down (each 12-20 kB). Every
transfer ends one of three ways:

* ``ok``      the client reported success and the bytes are exact (read from the control's
              folder for uploads, from the local file for downloads);
* ``caught``  a typed error (``DncError``): the link gave a telegram up, or the end-to-end check
              found a difference; nothing may be left at the destination;
* ``silent``  the client reported success and the bytes differ, or a failed transfer left a
              file: the one outcome that must never happen.

Also counted: telegram-size changes, transfers started again, text uploads that needed a
read-back, and payload throughput of the successful transfers.

Run alone (``--seconds``) or as the ``serial-lsv2`` pattern of ``benchmarks/soak.py``.

    .venv/bin/python benchmarks/soak_serial_lsv2.py --seconds 600
"""

from __future__ import annotations

import argparse
import json
import random
import shutil
import sys
import tempfile
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Protocol

from opendnc.errors import DncError
from opendnc.lsv2 import Client
from opendnc.lsv2.serial_stream import SerialLine
from opendnc.sim.cable import CableProcess
from opendnc.sim.tnc import start_tnc
from opendnc.sim.tnc.serial_front import attach_serial

BAUD = 115200
BER = 1e-4
CASES = ("text-up", "binary-up", "text-down", "binary-down")


@dataclass
class SerialTally:
    """Outcomes of one kind of transfer."""

    cases: int = 0
    ok: int = 0
    caught: int = 0
    silent: int = 0
    bytes_ok: int = 0
    seconds_ok: float = 0.0
    notes: list[str] = field(default_factory=list)

    @property
    def throughput(self) -> float:
        """Payload bytes per second of the successful transfers."""
        return self.bytes_ok / self.seconds_ok if self.seconds_ok else 0.0

    def note(self, text: str) -> None:
        if len(self.notes) < 4 and text not in self.notes:
            self.notes.append(text[:200])


@dataclass
class SerialSoak:
    """Counters of a serial soak (several rounds)."""

    tallies: dict[str, SerialTally] = field(
        default_factory=lambda: {c: SerialTally() for c in CASES}
    )
    rounds: int = 0
    telegram_changes: int = 0
    restarts: int = 0
    readbacks: int = 0
    parity_failed: int = 0


def nc_text(rng: random.Random, size: int) -> bytes:
    lines = [b"0 BEGIN PGM SOAK MM"]
    n = 1
    while sum(len(x) + 2 for x in lines) < size:
        lines.append(
            b"%d L X%+.3f Y%+.3f FMAX" % (n, rng.uniform(-500, 500), rng.uniform(-500, 500))
        )
        n += 1
    lines.append(b"%d END PGM SOAK MM" % n)
    return b"\r\n".join(lines) + b"\r\n"


def one_round(stats: SerialSoak, work: Path, rng: random.Random) -> None:
    """One cable, one control, the four transfers."""
    root = work / f"tnc{stats.rounds}"
    (root / "TNC").mkdir(parents=True)
    files = {
        "text": (f"S{stats.rounds}.H", nc_text(rng, rng.randrange(12_000, 20_000))),
        "binary": (f"s{stats.rounds}.bin", rng.randbytes(rng.randrange(12_000, 20_000))),
    }
    # the downloads' sources: written straight into the control's folder
    for name, data in files.values():
        (root / "TNC" / f"D{name}").write_bytes(data)
    seed = rng.randrange(2**31)
    with (
        CableProcess(baud=BAUD, bits_per_char=11, noise=BER, seed=seed, parity_check=True) as cable,
        start_tnc("tnc320", root=root) as tnc,
    ):
        attach_serial(tnc, cable.path_a, baud=BAUD)
        line = SerialLine(cable.path_b, BAUD, telegram_size=256)
        for case in CASES:
            kind, direction = case.split("-")
            name, data = files[kind]
            tally = stats.tallies[case]
            tally.cases += 1
            local = work / f"r{stats.rounds}-{case}"
            remote = f"TNC:/{name}" if direction == "up" else f"TNC:/D{name}"
            target = root / "TNC" / name
            if direction == "up":
                local.write_bytes(data)
            started = time.monotonic()
            try:
                with Client.over_serial(line, timeout=10) as client:
                    if direction == "up":
                        client.upload(local, remote, binary=kind == "binary")
                    else:
                        client.download(remote, local, binary=kind == "binary")
                    stats.telegram_changes += len(client.telegram_changes)
                    stats.restarts += client.serial_restarts
                    stats.readbacks += client.serial_readbacks
            except DncError as exc:
                tally.caught += 1
                tally.note(f"caught: {exc}")
                left = target if direction == "up" else local
                if left.exists():
                    tally.silent += 1
                    tally.note(f"silent: a failed {case} left {left.name}")
                continue
            took = time.monotonic() - started
            got = target.read_bytes() if direction == "up" else local.read_bytes()
            if got != data:
                tally.silent += 1
                tally.note(f"silent: {case} {len(got)} bytes, {len(data)} sent, seed {seed}")
                continue
            tally.ok += 1
            tally.bytes_ok += len(data)
            tally.seconds_ok += took
    report = cable.stats  # read when the cable stopped, after the control (no write to a gone pty)
    if report is not None:
        stats.parity_failed += report.parity_failed
    stats.rounds += 1


def soak_serial(seconds: float, seed: int, *, smoke: bool = False) -> SerialSoak:
    """Rounds until ``seconds`` have passed (``smoke``: one round)."""
    stats = SerialSoak()
    rng = random.Random(seed)
    deadline = time.monotonic() + seconds
    with tempfile.TemporaryDirectory(prefix="opendnc-soak-serial-") as folder:
        while True:
            one_round(stats, Path(folder), rng)
            if smoke or time.monotonic() >= deadline:
                break
    return stats


class _Tally(Protocol):
    cases: int
    caught: int
    silent: int
    notes: list[str]

    def fail(self, why: str) -> None: ...


class _Soak(Protocol):
    work: Path
    rng: random.Random
    smoke: bool

    def tally(self, name: str) -> _Tally: ...

    def time_left(self) -> float: ...


def pattern_serial_lsv2(soak: _Soak) -> None:
    """The ``serial-lsv2`` pattern of ``benchmarks/soak.py``: one round per turn."""
    stats = SerialSoak()
    work = soak.work / "serial-lsv2"
    # Each turn starts afresh (its round counter restarts at 0, so its folders would clash
    # with the last turn's; the 180 s soak ran one turn only).
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir()
    one_round(stats, work, soak.rng)
    for case, t in stats.tallies.items():
        tally = soak.tally(f"serial-{case}")
        tally.cases += t.cases
        tally.caught += t.caught
        tally.silent += t.silent
        for note in t.notes:
            if len(tally.notes) < 6 and note not in tally.notes:
                tally.notes.append(note)


def summary(stats: SerialSoak, seconds: float) -> dict[str, object]:
    return {
        "seconds": round(seconds, 1),
        "rounds": stats.rounds,
        "ber": BER,
        "baud": BAUD,
        "telegram_changes": stats.telegram_changes,
        "restarts": stats.restarts,
        "readbacks": stats.readbacks,
        "parity_failed": stats.parity_failed,
        "cases": {
            case: {**asdict(t), "throughput": round(t.throughput)}
            for case, t in stats.tallies.items()
        },
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=120.0, help="how long to soak")
    parser.add_argument("--smoke", action="store_true", help="one round")
    parser.add_argument("--seed", type=int, default=1, help="seed of every random choice")
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    args = parser.parse_args()
    started = time.monotonic()
    stats = soak_serial(args.seconds, args.seed, smoke=args.smoke)
    result = summary(stats, time.monotonic() - started)
    if args.json:
        print(json.dumps(result))
    else:
        print(
            f"serial LSV2 soak: {result['seconds']} s, {stats.rounds} rounds, {BAUD} 8E1, "
            f"bit-error rate {BER:g}, {stats.parity_failed} characters failed parity"
        )
        print(f"{'case':<14}{'cases':>7}{'ok':>6}{'caught':>8}{'silent':>8}{'B/s':>8}")
        for case, t in stats.tallies.items():
            print(f"{case:<14}{t.cases:>7}{t.ok:>6}{t.caught:>8}{t.silent:>8}{t.throughput:>8.0f}")
        print(
            f"telegram size changes {stats.telegram_changes}, transfers started again "
            f"{stats.restarts}, text uploads read back {stats.readbacks}"
        )
        for case, t in stats.tallies.items():
            for note in t.notes:
                print(f"  {case}: {note}")
    sys.exit(1 if any(t.silent for t in stats.tallies.values()) else 0)


if __name__ == "__main__":
    main()
