"""`opendnc sim cable`: a virtual null-modem cable between two pseudo-terminals."""

from __future__ import annotations

import signal
import sys
import threading
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING

import typer

from opendnc.cli.common import cli_errors, err_console, print_json
from opendnc.errors import TransportError

if TYPE_CHECKING:  # the cable runs on ptys: load it only when the command runs (POSIX)
    from opendnc.sim.cable import CableStats, LaneStats


def _lane_line(name: str, lane: LaneStats) -> str:
    return (
        f"{name}: carried {lane.carried}, delivered {lane.delivered}, "
        f"corrupted {lane.corrupted} ({lane.bit_flips} bits), dropped {lane.dropped}, "
        f"unheard {lane.unheard}"
    )


def _report(stats: CableStats, as_json: bool) -> None:
    if as_json:
        print_json(stats)
        return
    sys.stdout.write(_lane_line("a->b", stats.a_to_b) + "\n")
    sys.stdout.write(_lane_line("b->a", stats.b_to_a) + "\n")
    sys.stdout.write(
        f"total: carried {stats.carried}, corrupted {stats.corrupted}, dropped {stats.dropped}\n"
    )
    sys.stdout.flush()


def cable(
    baud: int = typer.Option(115200, "--baud", help="Line rate in bits per second."),
    bits_per_char: int = typer.Option(
        10, "--bits-per-char", help="Bits per character on the line (8N1 = 10, 8E1 = 11)."
    ),
    noise: float = typer.Option(0.0, "--noise", help="Bit-error rate per data bit (e.g. 1e-5)."),
    drop: float = typer.Option(0.0, "--drop", help="Probability that a byte is lost."),
    seed: int | None = typer.Option(None, "--seed", help="Seed for reproducible faults."),
    link_a: Path | None = typer.Option(None, "--link-a", help="Symlink to create for side A."),
    link_b: Path | None = typer.Option(None, "--link-b", help="Symlink to create for side B."),
    monitor: Path | None = typer.Option(
        None,
        "--monitor",
        help="Write a timestamped hex line for every delivery in either direction to this file.",
    ),
    as_json: bool = typer.Option(False, "--json", help="Print the final counters as JSON."),
    parity_check: bool = typer.Option(
        False,
        "--parity-check",
        help="Model the parity bit (8E1, 7E1): a character with an odd number of flipped bits "
        "fails the check and arrives as the receiving port's settings ask: unchanged (no "
        "INPCK), as NUL (INPCK), dropped (IGNPAR) or marked FF 00 c (PARMRK).",
    ),
) -> None:
    """Join two pseudo-terminals like a serial cable, at line speed, with optional faults.

    The first line of output holds the two device paths ("PATH_A PATH_B"). The cable runs
    until interrupted (Ctrl-C or SIGTERM), then prints how many bytes it carried, corrupted
    and dropped in each direction.
    """
    with cli_errors():
        stop = threading.Event()

        def on_signal(signum: int, frame: FrameType | None) -> None:
            stop.set()

        previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
        try:
            from opendnc.sim.cable import VirtualCable

            virtual = VirtualCable(
                baud,
                bits_per_char,
                noise,
                drop,
                seed,
                link_a=link_a,
                link_b=link_b,
                monitor=monitor,
                parity_check=parity_check,
            )
            with virtual:
                # scripts read this line to find the devices: keep it first and flush it now
                sys.stdout.write(f"{virtual.path_a} {virtual.path_b}\n")
                sys.stdout.flush()
                err_console.print(
                    f"cable up: {baud} baud, {bits_per_char} bits/char "
                    f"({virtual.bytes_per_second:g} bytes/s each way), noise {noise:g}, "
                    f"drop {drop:g}, seed {seed}"
                    + (f", links {link_a} {link_b}" if link_a or link_b else "")
                    + (f", monitor {monitor}" if monitor else ""),
                    highlight=False,
                    soft_wrap=True,
                )
                while not stop.wait(0.2):
                    if not virtual.running:
                        raise virtual.error or TransportError("virtual cable stopped")
            _report(virtual.stats, as_json)
            if virtual.monitor_error is not None:
                err_console.print(f"warning: {virtual.monitor_error}", highlight=False)
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)
