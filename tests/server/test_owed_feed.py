"""A control owed the rest of a fenced drip-feed hears nothing else first, even when the claim
of the continuation misses (a lease not confirmed at that moment, seen under load).

The server runs in this process on PostgreSQL, as a member of a cluster; the test plays the
old server through the database: it holds the machine's lease, runs the feed (the first blocks
and part of the next go to a virtual serial Haas that waits in DNC mode for the rest), stops
renewing, and once the server has taken the machine over writes the old feed's exact position.
The server's claims miss for a while after that. A status poll or a listener's NAK sent to the
control meanwhile would be read as part of its half-received block: the blocks it ran must be
the program's, once, in order.
"""

from __future__ import annotations

import hashlib
import threading
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from tests.peers import require_module

require_module("psycopg")
require_module("fastapi")

from opendnc.server.app import build  # noqa: E402
from opendnc.server.config.shop import parse_config  # noqa: E402
from opendnc.server.fleet.tasks import OWED  # noqa: E402
from opendnc.server.jobs import queue as jobs  # noqa: E402
from opendnc.server.jobs.executors import Claimed  # noqa: E402
from opendnc.server.library import versions as library  # noqa: E402
from opendnc.server.machines.leases import Leases  # noqa: E402
from opendnc.server.store.models import JobKind, JobState  # noqa: E402
from opendnc.sim.fleet import server_config  # noqa: E402
from opendnc.transport.urls import open_stream  # noqa: E402
from tests.server.conftest import _pg_database  # noqa: E402
from tests.server.harness import wait_for  # noqa: E402
from tests.server.inproc_server import Running  # noqa: E402
from tests.server.test_db_silence import Blocks, program_blocks  # noqa: E402
from tests.server.test_from_the_control import FleetThread  # noqa: E402

LEASE = 3.0
MACHINE = "haas-serial-1"
MOVES = "".join(f"G01 X{i % 50}.5 Y{i % 7}. F30.\n" for i in range(300))
PROGRAM = f"%\nO03002 (OWED)\nG20\nT1 M06\n{MOVES}M30\n%\n".encode()
FED = 20  # program lines the old server wrote whole; then part of the next one
PART = b"G01 X1"


@pytest.fixture
def pg_url() -> Iterator[str]:
    yield from _pg_database()


class Doubt:
    """Wraps the runner's claim: while set, every claim misses, as one does when the lease
    could not be confirmed at that moment; counts the misses."""

    def __init__(self, claim: Callable[[str], Claimed | None]) -> None:
        self.claim = claim
        self.on = threading.Event()
        self.missed = 0

    def __call__(self, machine: str) -> Claimed | None:
        if self.on.is_set():
            self.missed += 1
            return None
        return self.claim(machine)


@pytest.mark.parametrize("written", ["after the take-over", "before the take-over"])
def test_a_control_owed_the_rest_of_a_feed_hears_nothing_before_it(
    tmp_path: Path, pg_url: str, written: str
) -> None:
    # after: the new server waits for the old one's position, then claims
    # before: the old server wrote it while it still held the lease (its job ended, the
    # continuation queued); the new server finds the continuation when it gains the machine
    fleet = FleetThread(
        tmp_path / "machines", tnc=0, haas=0, serial_haas=1, block_rate=200, dnc_timeout=120
    )
    running: Running | None = None
    try:
        front = fleet.fleet.serial_ports[MACHINE]
        blocks = Blocks()
        front.dnc_sha256 = blocks  # type: ignore[assignment]
        text = server_config(
            fleet.fleet, poll_interval=0.3, library=tmp_path / "lib", dripfeed=True
        )
        text = text.replace(
            "[server]\n",
            f'[server]\nname = "dnc-new"\nlease_seconds = {LEASE}\nresume_wait = 40\n',
            1,
        )
        config = parse_config(text, base=tmp_path)
        server = build(config, database=pg_url, sweep_interval=0.3)
        doubt = Doubt(server.runner._claim)
        server.runner._claim = doubt  # type: ignore[method-assign]

        # the old server: its lease, its drip-feed running, the first blocks at the control
        with server.sessions.begin() as session:
            jobs.sync_machines(session, config.machines)
            library.add_version(session, "O03002.nc", PROGRAM, author="test")
            library.release(session, "O03002.nc", 1, actor="test")
        old = Leases(server.sessions, "dnc-old", {MACHINE: frozenset()}, ttl=LEASE)
        wait_for("the old server's lease", lambda: MACHINE in old.renew().held)
        with server.sessions.begin() as session:
            version = library.get_version(session, "O03002.nc", 1)
            job_id = jobs.enqueue(
                session, JobKind.DRIPFEED, MACHINE, actor="test", version=version
            ).id
        with server.sessions.begin() as session:
            claimed = jobs.claim(session, MACHINE, "dnc-old")
            assert claimed is not None
            assert claimed.id == job_id
        lines = PROGRAM.split(b"\n")
        offset = sum(len(line) + 1 for line in lines[: 2 + FED])
        assert PROGRAM[offset:].startswith(PART)
        machine = fleet.fleet.machines[0]
        port = open_stream(machine.serial, machine.baud)
        try:
            port.write(PROGRAM[:offset] + PART)
            port.drain()
        finally:
            port.close()
        wait_for("the first blocks at the control", lambda: front.dnc_lines == FED)

        def position() -> int:
            # the old server's word: the rest of line FED + 3 (PART written), the lines after
            doubt.on.set()
            with server.sessions.begin() as session:
                return jobs.resume(
                    session, job_id, actor="dnc-old", offset=offset, written=PART, line=FED + 3
                ).id

        if written == "before the take-over":
            with server.sessions.begin() as session:
                jobs.fail(session, job_id, "paused by its fence", retryable=False, line=FED + 3)
            follow = position()
        # the server takes the machine once the old lease has run out
        running = Running(server)

        def taken_over() -> bool:
            with server.sessions() as session:
                job = jobs.get_job(session, job_id)
                return job.state is JobState.INTERRUPTED

        if written == "after the take-over":
            wait_for("the take-over", taken_over, timeout=20)  # a lease and a renewal, loaded
            follow = position()
        # the machine's task goes round several times without getting the continuation
        wait_for("claims that miss", lambda: doubt.missed >= 3, timeout=20)
        assert front.dnc_lines == FED
        # the machine's card says why it has no fresh status
        status = server.machines.machines[MACHINE].status
        assert status is not None
        assert status.message == OWED
        doubt.on.clear()

        def ended() -> JobState | None:
            with server.sessions() as session:
                state = jobs.get_job(session, follow).state
                return state if state.finished else None

        assert wait_for("the continuation to end", ended, timeout=60) is JobState.DONE
        body = program_blocks(PROGRAM)
        wait_for(
            "every block at the control",
            lambda: len(blocks.lines) >= len(body),
            timeout=30,
            describe=lambda: blocks.first_difference(PROGRAM),
        )
        want = hashlib.sha256(b"".join(body)).hexdigest()
        assert blocks.hexdigest() == want, blocks.first_difference(PROGRAM)
        assert not front.control.machine.alarms
        assert not [m for m in front.messages if "ABORT" in m], front.messages
    finally:
        if running is not None:
            running.stop()
            running.server.engine.dispose()
        fleet.stop()
