"""Live status of a classic Haas on RS-232 (``mdc = true``): program, mode and parts by MDC
Q-commands on the port the server also listens on for XModem between jobs."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.server.conftest import on
from tests.server.harness import wait_jobs
from tests.server.srvx_support import (
    STORED,
    FleetThread,
    Procs,
    auth,
    interrupt_dripfeed,
    serve_fleet,
    slow_serial_haas,
    wait_for,
)


@pytest.fixture
def haas(tmp_path: Path) -> Iterator[FleetThread]:
    fleet = FleetThread(tmp_path / "machines", tnc=0, haas=0, serial_haas=1)
    try:
        yield fleet
    finally:
        fleet.stop()


def _status(client: Any, key: str) -> dict[str, Any]:
    machines = client.get("/api/machines", headers=auth(key)).json()
    found = [m for m in machines if m["name"] == "haas-serial-1"]
    status: dict[str, Any] = (found[0]["status"] if found else None) or {}
    return status


@on("sqlite")
def test_status_by_mdc_on_the_serial_port_and_a_punch_still_arrives(
    tmp_path: Path, haas: FleetThread, procs: Procs, db_url: str
) -> None:
    sim = haas.fleet.sims["haas-serial-1"]
    port = haas.fleet.serial_ports["haas-serial-1"]

    def set_state(program: str, parts: int) -> None:
        def change() -> None:
            sim.control.machine.program = program
            sim.control.machine.m30_counter_1 = parts

        haas.call(change)

    set_state("O04321", 12)
    haas.call(lambda: sim.control.save_program(STORED))
    client, key = serve_fleet(tmp_path, haas, procs, db_url)
    with client:
        status = wait_for(
            "the program and parts from Q500",
            lambda: (s := _status(client, key)).get("program") == "O04321" and s,
            describe=lambda: (_status(client, key), procs.log("server")),
        )
        assert (status["part_count"], status["execution"]) == (12, "READY")
        # Q104's MDI (the control's word, kept) in MTConnect's CONTROLLER_MODE words
        assert (status["mode"], status["native_mode"]) == ("MANUAL_DATA_INPUT", "MDI")
        assert status["available"] is True
        set_state("O01234", 13)  # the operator ran the next part
        wait_for(
            "the new state",
            lambda: (
                (_status(client, key).get("program"), _status(client, key).get("part_count"))
                == ("O01234", 13)
            ),
            describe=lambda: _status(client, key),
        )
        answered = port.mdc_replies
        assert answered >= 4  # Q500 and Q104 per poll, several polls
        # Between the polls the port still listens: the operator's punch lands in the inbox.
        port.select("punch:O1234")
        items = wait_for(
            "the punch in the inbox",
            lambda: client.get("/api/inbox", headers=auth(key)).json(),
            describe=lambda: (port.messages, procs.log("server")),
        )
        assert [(i["name"], i["state"]) for i in items] == [("O01234.nc", "new")]
        got = client.get(f"/api/inbox/{items[0]['id']}/content", headers=auth(key)).content
        assert got.decode().split() == STORED.split()
        # ... and the status polls go on after it.
        wait_for("more MDC replies", lambda: port.mdc_replies > answered + 2)
        assert _status(client, key).get("program") == "O01234"
    assert "RS232 ABORT" not in " ".join(port.messages)


QUIET = 30.0  # seconds the server's port stays silent after a broken feed (docs/server.md)


@on("postgresql")
def test_after_a_broken_feed_and_its_restart_the_status_asks_the_control_again(
    tmp_path: Path, procs: Procs, db_url: str
) -> None:
    fleet = slow_serial_haas(tmp_path / "machines")
    try:
        front = fleet.fleet.serial_ports["haas-serial-1"]
        control = fleet.fleet.sims["haas-serial-1"].control
        client, key = serve_fleet(tmp_path, fleet, procs, db_url, machine_keys="dripfeed = true\n")
        with client:
            wait_for("the first MDC status", lambda: _status(client, key).get("native_mode"))
            job_id, _first, stopped_at = interrupt_dripfeed(client, key, front)
            broke = time.monotonic()
            # The feed broke: what the server was doing to the machine is its state, an
            # alarm that names the drip-feed and its program (docs/dashboard.md), not READY.
            quiet = wait_for(
                "the status of the broken feed",
                lambda: "drip-feed" in (s := _status(client, key)).get("message", "") and s,
                describe=lambda: _status(client, key),
            )
            assert (quiet["execution"], quiet["program"]) == ("INTERRUPTED", "O03000.nc"), quiet
            wait_for("the control's DNC link alarm", lambda: front.messages)
            fleet.call(control.reset)  # the operator's RESET, then the restart from the line
            again = client.post(
                f"/api/jobs/{job_id}/retry", headers=auth(key), json={"from_line": stopped_at}
            )
            assert again.status_code == 201, again.text
            (done,) = wait_jobs(client, key, [again.json()["id"]])
            assert done["state"] == "done", done["error"]
            # The control has the whole program: the server asks it again at once, not only
            # when the quiet after the break would have ended. Counted where the questions
            # arrive, at the control: on a loaded machine its answer can miss the server's
            # one second and the status then says so until the next poll (seen in CI).
            asked = front.mdc_replies
            wait_for(
                "an MDC question after the restart",
                lambda: front.mdc_replies > asked,
                # before the quiet would have ended; at least 5 s (a loaded machine may take
                # most of the quiet to run the restart)
                max(5.0, QUIET - (time.monotonic() - broke) - 2.0),
                describe=lambda: (_status(client, key), front.messages),
            )
            status = wait_for(
                "the program and mode by MDC after the restart",
                lambda: (s := _status(client, key)).get("program") == "O03000" and s,
                describe=lambda: (_status(client, key), front.messages),
            )
            assert (status["mode"], status["native_mode"]) == ("AUTOMATIC", "DNC")
            assert status["part_count"] == 1  # the restart ran to its M30
    finally:
        fleet.stop()
