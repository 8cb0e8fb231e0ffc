"""A take-over after SIGKILL sends no load the control already has: two servers on one real
PostgreSQL database around virtual TNCs that note every program they receive completely.

The server running a load is frozen (SIGSTOP) the moment its control has the whole program,
while the job still reads running in the database (the old server's read-back and its
"done" had not happened), then killed. The machine's new server asks the control before
sending again: the program arrived once, the job ends done, and its audit row says it was
already there. A load the control does not have yet is sent by the new server, once.
"""

from __future__ import annotations

import os
import signal
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from opendnc.server.jobs.executors import ALREADY_AT_CONTROL
from tests.server.cluster_support import (
    TAKEOVER_LIMIT,
    Cluster,
    audit_rows,
    publish_programs,
    sha,
    start_cluster,
    wait_all_ended,
)
from tests.server.conftest import _pg_database
from tests.server.harness import Procs


@pytest.fixture
def pg_url() -> Iterator[str]:
    """A fresh PostgreSQL database (several servers need one)."""
    yield from _pg_database()


def _job(cluster: Cluster, via: str, job_id: int) -> dict[str, Any]:
    found: dict[str, Any] = cluster.clients[via].get(f"/api/jobs/{job_id}").json()
    return found


def _freeze_once_received(
    cluster: Cluster, victim: str, machine: str, name: str, data: bytes, job_id: int
) -> bool:
    """SIGSTOP ``victim`` as soon as ``machine`` has the whole program; True if the job still
    reads running then (the window this test is about), False if it had already ended."""
    key = (machine, name, sha(data))
    # A tight poll of one small file (wait_for's pause grows to a quarter of a second, longer
    # than the window), bounded by a deadline.
    deadline = time.monotonic() + 60
    while cluster.receipts_by()[key] < 1:
        assert time.monotonic() < deadline, f"{machine} never received {name}"
        time.sleep(0.005)
    os.killpg(cluster.procs.procs[victim].pid, signal.SIGSTOP)
    return bool(_job(cluster, "dnc-1", job_id)["state"] == "running")


def test_a_takeover_sends_no_load_the_control_already_has(
    tmp_path: Path, pg_url: str, procs: Procs
) -> None:
    # Every telegram answered 20 ms late: the old server's read-back of a program takes long
    # enough for the test to freeze it between the control's receipt and the job's end.
    cluster = start_cluster(procs, tmp_path, pg_url, tnc=2, latency_ms=20.0)
    try:
        cluster.start("dnc-1", "dnc-2")
        owners = cluster.wait_settled("dnc-1", {"dnc-1", "dnc-2"})
        victim = "dnc-2"
        machine = next(m for m, owner in owners.items() if owner == victim)
        programs = publish_programs(cluster.clients["dnc-1"], 3, 30_000)
        names = sorted(programs)

        # Loads until one is caught in the window (the first, almost always).
        caught: tuple[int, str] | None = None
        for name in names[:2]:
            sent = cluster.clients["dnc-1"].post(
                "/api/jobs", json={"program": name, "machines": [machine]}
            )
            assert sent.status_code == 201, sent.text
            job_id = sent.json()[0]["id"]
            if _freeze_once_received(cluster, victim, machine, name, programs[name], job_id):
                caught = (job_id, name)
                break
            os.killpg(cluster.procs.procs[victim].pid, signal.SIGCONT)
            wait_all_ended(cluster.clients["dnc-1"], [job_id])
        assert caught is not None, "no load was caught between its receipt and its end"
        job_id, name = caught
        # A second load waits behind it: the control does not have that one.
        behind = names[2]
        queued = cluster.clients["dnc-1"].post(
            "/api/jobs", json={"program": behind, "machines": [machine]}
        )
        assert queued.status_code == 201, queued.text
        second = queued.json()[0]["id"]

        cluster.kill(victim)  # SIGKILL of the frozen server: no clean stop, no end written
        killed = time.monotonic()
        ended = wait_all_ended(cluster.clients["dnc-1"], [job_id, second], TAKEOVER_LIMIT * 3)
        print(f"both loads ended {time.monotonic() - killed:.1f} s after the kill")
        assert {j["id"]: j["state"] for j in ended} == {job_id: "done", second: "done"}

        # Counted at the control: each program arrived exactly once.
        received = cluster.receipts_by()
        for program in (name, behind):
            assert received[(machine, program, sha(programs[program]))] == 1, (program, received)
        stored = cluster.root / "machines" / machine / "TNC" / "nc_prog" / name
        assert stored.read_bytes() == programs[name]

        # The trail says which: the take-over by dnc-1, then "already there" for that job.
        takeovers = [r for r in audit_rows(cluster.db, "job.takeover") if r["job_id"] == job_id]
        assert [(r["actor"], r["previous"]) for r in takeovers] == [("dnc-1", victim)]
        done = [
            r
            for r in audit_rows(cluster.db, "job.send")
            if r["job_id"] == job_id and r.get("verification")
        ]
        assert [(r["actor"], r["verification"], r["sent"]) for r in done] == [
            ("dnc-1", ALREADY_AT_CONTROL, False)
        ]
        others = [r for r in audit_rows(cluster.db, "job.send") if r["job_id"] == second]
        assert all(r.get("sent", True) for r in others)
    finally:
        procs.stop_all()
        cluster.close()
