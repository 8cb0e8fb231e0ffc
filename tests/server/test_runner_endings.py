"""How jobs end when the control lets them down: a read-back that finds other bytes than were
loaded fails the attempt (the load is retried, and fails for good after its attempts), and a
serial Haas that goes silent mid-load ends the attempt within its profile's timeout instead
of being waited for block after block."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.peers import require_module

require_module("fastapi")

from sqlalchemy import select  # noqa: E402

from opendnc.server.app import build  # noqa: E402
from opendnc.server.config.shop import parse_config  # noqa: E402
from opendnc.server.jobs import queue as jobs  # noqa: E402
from opendnc.server.kinds.haas_serial.connector import XMODEM_SILENCE_FLOOR  # noqa: E402
from opendnc.server.library import versions as library  # noqa: E402
from opendnc.server.store.models import AuditEntry, JobKind, JobState  # noqa: E402
from opendnc.sim.fleet import server_config  # noqa: E402
from tests.server.harness import wait_for  # noqa: E402
from tests.server.inproc_server import (  # noqa: E402
    PROGRAM,
    Running,
    Shop,
)
from tests.server.test_from_the_control import FleetThread  # noqa: E402

TAMPERED = PROGRAM.replace(b"X1. ", b"X7. ")


def _rows(shop: Shop, job_id: int) -> list[tuple[str, str]]:
    with shop.server.sessions() as session:
        rows = session.scalars(
            select(AuditEntry)
            .where(AuditEntry.job_id == job_id, AuditEntry.action == "job.send")
            .order_by(AuditEntry.id)
        )
        return [(r.result, str((r.detail or {}).get("error", ""))) for r in rows]


def test_a_read_back_that_differs_fails_the_attempt_and_the_retry_loads_it(shop: Shop) -> None:
    target = shop.root / "TNC" / "nc_prog" / "O01234.nc"
    shop.gates.hold("verify")
    job_id = shop.queue()
    shop.server.machines.wake(shop.machine)
    assert shop.gates.reached["verify"].wait(30)
    assert target.read_bytes() == PROGRAM  # loaded; now someone changes it at the control
    target.write_bytes(TAMPERED)
    shop.gates.go["verify"].set()
    job = shop.ended(job_id)
    assert (job.state, job.attempts) == (JobState.DONE, 2)
    first, second = _rows(shop, job_id)
    assert first[0] == "retry"
    assert "the control holds different bytes after the load" in first[1]
    assert second == ("ok", "")
    assert target.read_bytes() == PROGRAM


def test_a_read_back_that_always_differs_fails_the_job_after_its_attempts(shop: Shop) -> None:
    target = shop.root / "TNC" / "nc_prog" / "O01234.nc"
    # held before the job is queued: the runner's sweep may start it at once (seen at -n 12:
    # its first attempt had verified and ended before the gate was set)
    shop.gates.hold("verify")
    job_id = shop.queue()
    with shop.server.sessions() as session:
        attempts = jobs.get_job(session, job_id).max_attempts
    shop.server.machines.wake(shop.machine)
    for attempt in range(1, attempts + 1):
        assert shop.gates.reached["verify"].wait(30), f"attempt {attempt} never verified"
        target.write_bytes(TAMPERED)
        go = shop.gates.go["verify"]
        if attempt < attempts:
            shop.gates.hold("verify")  # the next attempt stops there too
        go.set()
    job = shop.ended(job_id)
    assert (job.state, job.attempts) == (JobState.FAILED, attempts)
    assert "different bytes" in job.error
    results = [r for r, _ in _rows(shop, job_id)]
    assert results == ["retry"] * (attempts - 1) + ["failed"]


BIG = b"%\r\nO01235 (BIG)\r\n" + b"".join(b"G01 X%d.25 Y2. F50.\r\n" % i for i in range(2500))
BIG += b"M30\r\n%\r\n"
SILENCE = 12.0  # the profile's idle_timeout in this test (above the XModem floor)


@pytest.fixture
def serial_shop(tmp_path: Path) -> Iterator[tuple[FleetThread, Running]]:
    fleet = FleetThread(tmp_path / "machines", tnc=0, haas=0, serial_haas=1, baud=38400)
    running = None
    try:
        text = server_config(fleet.fleet, poll_interval=0.3, library=tmp_path / "lib", check="warn")
        text = text.replace(
            "serial_profile = { baud = 38400 }",
            f"serial_profile = {{ baud = 38400, idle_timeout = {SILENCE:g} }}",
        )
        assert f"idle_timeout = {SILENCE:g}" in text
        server = build(
            parse_config(text, base=tmp_path),
            database=f"sqlite:///{tmp_path / 'db.sqlite'}",
            retry_backoff=30.0,  # the retry waits: this test looks at the first attempt only
        )
        with server.sessions.begin() as session:
            library.add_version(session, "O01235.nc", BIG, author="test")
            library.release(session, "O01235.nc", 1, actor="test")
        running = Running(server)
        yield fleet, running
    finally:
        if running is not None:
            running.stop()
            running.server.engine.dispose()
        fleet.stop()


def test_a_serial_haas_that_goes_silent_mid_load_ends_the_attempt_in_its_timeout(
    serial_shop: tuple[FleetThread, Running],
) -> None:
    assert SILENCE > XMODEM_SILENCE_FLOOR
    fleet, running = serial_shop
    server = running.server
    name = fleet.fleet.machines[0].name
    state = server.machines.machines[name]
    wait_for("the serial Haas online", lambda: state.online)
    with server.sessions.begin() as session:
        version = jobs.version_to_send(session, "O01235.nc", None)  # the released one
        job_id = jobs.enqueue(session, JobKind.SEND, name, actor="test", version=version).id
    server.machines.wake(name)
    wait_for("the load under way", lambda: state.job_id == job_id and state.job_progress[0] > 0)
    front = fleet.fleet.serial_ports[name]
    fleet.run(front.close)  # the control dies: its end of the cable says nothing any more
    died = time.monotonic()

    def ended() -> list[AuditEntry]:
        with server.sessions() as session:
            return list(
                session.scalars(
                    select(AuditEntry).where(
                        AuditEntry.job_id == job_id, AuditEntry.action == "job.send"
                    )
                )
            )

    rows = wait_for("the attempt to end", ended, timeout=SILENCE + 30)
    took = time.monotonic() - died
    assert took < SILENCE + 3.0, took
    assert rows[0].result == "retry"
    assert "went silent for 12 s" in str(rows[0].detail.get("error"))
    with server.sessions() as session:
        assert jobs.get_job(session, job_id).state is JobState.QUEUED  # a load is retried
