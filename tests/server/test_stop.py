"""SIGTERM and SIGINT stop ``opendnc serve`` within its deadline (10 s by default) whatever it
is doing: 200 virtual machines polled, an event stream open, on SQLite and PostgreSQL, signalled
again and again.

The rounds are a parameter: ``OPENDNC_STOP_ROUNDS`` (default 2: one SIGTERM, one SIGINT) and
``OPENDNC_STOP_MACHINES`` (default 200); ``benchmarks/stop.py`` runs 50 rounds and prints the
figures each round's line below gives.
"""

from __future__ import annotations

import os
import signal
import statistics
import threading
import time
from pathlib import Path

from opendnc.cli.serve import STOP_TIMEOUT
from tests.server.conftest import on
from tests.server.harness import Procs, auth, create_key, httpx, serve, wait_for

ROUNDS = int(os.environ.get("OPENDNC_STOP_ROUNDS", "2"))
MACHINES = int(os.environ.get("OPENDNC_STOP_MACHINES", "200"))
SLACK = 1.0  # seconds beyond the deadline for the process to be reaped


def _fleet(procs: Procs, tmp_path: Path, machines: int) -> Path:
    config = tmp_path / "shop.toml"
    procs.start(
        "fleet",
        "sim",
        "fleet",
        "--tnc",
        str(machines // 2),
        "--haas",
        str(machines - machines // 2),
        "--root",
        str(tmp_path / "machines"),
        "--config-out",
        str(config),
        "--poll",
        "1.0",
    )
    wait_for(
        "the fleet",
        lambda: "listening" in procs.log("fleet"),
        timeout=180,
        describe=lambda: procs.log("fleet")[-2000:],
    )
    return config


def _stream(url: str, key: str, stop: threading.Event) -> None:
    """Hold the event stream open (a connection that never ends by itself)."""
    try:
        with (
            httpx.Client(base_url=url, timeout=None) as client,
            client.stream("GET", "/api/events", headers=auth(key)) as reply,
        ):
            for _chunk in reply.iter_bytes():
                if stop.is_set():
                    return
    except httpx.HTTPError:
        return  # the server went away: what the test wanted


@on("postgresql")  # its connections are the harder ones to close in time
def test_signals_stop_a_busy_server_within_the_deadline(
    tmp_path: Path, procs: Procs, db_url: str
) -> None:
    config = _fleet(procs, tmp_path, MACHINES)
    key = create_key(config, db_url)
    took: list[float] = []
    for round_ in range(ROUNDS):
        sig = signal.SIGTERM if round_ % 2 == 0 else signal.SIGINT
        url = serve(procs, config, db_url)
        proc = procs.procs["server"]
        with httpx.Client(base_url=url, timeout=30) as client:

            def online() -> int:
                listed = client.get("/api/machines", headers=auth(key)).json()
                return sum(1 for m in listed if m["online"])

            wait_for("every machine online", lambda: online() == MACHINES, timeout=180)
        stop_stream = threading.Event()
        streaming = threading.Thread(target=_stream, args=(url, key, stop_stream), daemon=True)
        streaming.start()
        time.sleep(0.5)  # the stream is open and receiving
        began = time.monotonic()
        os.kill(proc.pid, sig)
        proc.wait(STOP_TIMEOUT + 30)
        took.append(time.monotonic() - began)
        print(f"\nround {round_ + 1}: {sig.name} stopped in {took[-1]:.2f} s", flush=True)
        stop_stream.set()
        procs.procs.pop("server")
    backend = db_url.split(":", 1)[0]
    log = procs.log("server")
    cut = log.count("the server did not stop within")  # the watchdog's line
    print(
        f"\nstop rounds on {backend}: {ROUNDS} with {MACHINES} machines; seconds "
        f"median {statistics.median(took):.2f}, max {max(took):.2f}; "
        f"ended by the watchdog {cut}; all {', '.join(f'{t:.2f}' for t in took)}"
    )
    assert max(took) < STOP_TIMEOUT + SLACK, log[-3000:]
    assert cut == 0, log[-3000:]
