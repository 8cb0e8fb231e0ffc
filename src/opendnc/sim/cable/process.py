"""The virtual cable in its own process, for benchmarks and tests of CPU-heavy code.

:class:`~opendnc.sim.cable.link.VirtualCable` pumps in a thread, which must win the GIL on time
to keep its deadlines. When the code under test burns CPU in the same interpreter (a pure-Python
CRC, PyPI ``xmodem``), run the cable as ``opendnc sim cable`` in a child process instead::

    with CableProcess(baud=115200) as cable:
        ...open cable.path_a and cable.path_b...
    print(cable.stats)      # final counters, read from the child's JSON report
"""

from __future__ import annotations

import json
import os
import selectors
import signal
import subprocess
import sys
from types import TracebackType
from typing import Any

from opendnc.errors import TransportError
from opendnc.sim.cable.link import CableStats, LaneStats

START_TIMEOUT = 60.0  # a Python start on a loaded machine: 15 s was passed at load 40


class CableProcess:
    """Runs ``opendnc sim cable --json`` as a child process; same settings as VirtualCable."""

    def __init__(
        self,
        baud: int = 115200,
        bits_per_char: int = 10,
        noise: float = 0.0,
        drop: float = 0.0,
        seed: int | None = None,
        monitor: str | os.PathLike[str] | None = None,
        parity_check: bool = False,
    ) -> None:
        self.args = [
            sys.executable,
            "-m",
            "opendnc.cli.main",
            "sim",
            "cable",
            "--json",
            f"--baud={baud}",
            f"--bits-per-char={bits_per_char}",
            f"--noise={noise!r}",
            f"--drop={drop!r}",
        ]
        if seed is not None:
            self.args.append(f"--seed={seed}")
        if monitor is not None:
            self.args.append(f"--monitor={os.fspath(monitor)}")
        if parity_check:
            self.args.append("--parity-check")
        self.path_a = ""
        self.path_b = ""
        self.stats: CableStats | None = None  # set by close()
        self._proc: subprocess.Popen[str] | None = None

    def start(self) -> CableProcess:
        """Start the child and wait for the two device paths on its first line."""
        proc = subprocess.Popen(
            self.args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )
        self._proc = proc
        assert proc.stdout is not None
        with selectors.DefaultSelector() as sel:
            sel.register(proc.stdout, selectors.EVENT_READ)
            ready = sel.select(timeout=START_TIMEOUT)
        line = proc.stdout.readline() if ready else ""
        paths = line.split()
        if len(paths) != 2:
            self._kill()
            why = line.strip() or _last_line(proc.communicate(timeout=5)[1]) or "no output"
            raise TransportError(f"virtual cable did not start: {why}")
        self.path_a, self.path_b = paths
        return self

    def close(self) -> CableStats | None:
        """Stop the child (SIGTERM) and return its final counters."""
        proc = self._proc
        if proc is None or self.stats is not None:
            return self.stats
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
        try:
            out, err = proc.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            self._kill()
            raise TransportError("virtual cable did not stop on SIGTERM") from None
        if proc.returncode != 0:
            raise TransportError(f"virtual cable failed: {err.strip()}")
        self.stats = _parse_stats(out)
        return self.stats

    def _kill(self) -> None:
        if self._proc is not None and self._proc.poll() is None:
            self._proc.kill()
            self._proc.wait(5)

    def __enter__(self) -> CableProcess:
        return self.start()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if exc_type is None:
            self.close()
        else:
            self._kill()
            proc = self._proc
            for pipe in (proc.stdout, proc.stderr) if proc is not None else ():
                if pipe is not None:
                    pipe.close()  # else a failed test leaves them to the GC (ResourceWarning)


def _last_line(text: str) -> str:
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    return lines[-1] if lines else ""


def _parse_stats(text: str) -> CableStats:
    try:
        raw: dict[str, Any] = json.loads(text)
        return CableStats(LaneStats(**raw["a_to_b"]), LaneStats(**raw["b_to_a"]))
    except (ValueError, KeyError, TypeError) as exc:
        raise TransportError(f"unreadable cable report: {text[:200]!r}") from exc
