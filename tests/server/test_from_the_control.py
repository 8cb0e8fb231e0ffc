"""Programs that start at the control: a Haas punch lands in the inbox, a remote request is
answered with the program and a report of what could not be sent.

The virtual Haas runs in this process (its serial port is pressed like the operator would,
``select("punch:O1234")``), on a virtual RS-232 cable; the server runs as its own process.
"""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Callable, Iterator
from concurrent.futures import Future
from datetime import datetime
from pathlib import Path
from typing import Any, TypeVar

import pytest

from opendnc.sim.fleet import Fleet, server_config, start_fleet
from tests.server.conftest import on
from tests.server.harness import (
    Procs,
    auth,
    create_key,
    httpx,
    start_server,
    wait_for,
    wait_jobs,
)

T = TypeVar("T")
DELAY = 0.5  # the request delay of these tests' server


class FleetThread:
    """A fleet on its own event loop thread."""

    def __init__(self, root: Path, **counts: int) -> None:
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()
        self.fleet: Fleet = self.run(lambda: start_fleet(root, **counts))

    def run(self, make: Callable[[], Any]) -> Any:
        return asyncio.run_coroutine_threadsafe(make(), self.loop).result(30)

    def call(self, fn: Callable[[], T]) -> T:
        future: Future[T] = Future()

        def go() -> None:
            try:
                future.set_result(fn())
            except BaseException as exc:
                future.set_exception(exc)

        self.loop.call_soon_threadsafe(go)
        return future.result(10)

    def stop(self) -> None:
        self.run(self.fleet.close)
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(10)
        self.loop.close()


@pytest.fixture
def haas(tmp_path: Path) -> Iterator[FleetThread]:
    fleet = FleetThread(tmp_path / "machines", tnc=0, haas=0, serial_haas=1)
    try:
        yield fleet
    finally:
        fleet.stop()


def _server(
    tmp_path: Path,
    haas: FleetThread,
    procs: Procs,
    db_url: str,
    *,
    dripfeed: bool = False,
    extra: str = "",
    check: str = "warn",
) -> tuple[httpx.Client, str]:
    config = tmp_path / "shop.toml"
    text = server_config(
        haas.fleet,
        poll_interval=0.5,
        library=tmp_path / "lib",
        dripfeed=dripfeed,
        check=check,
    )
    config.write_text(text + f"\n[requests]\ndelay = {DELAY}\n" + extra)
    key = create_key(config, db_url)
    return start_server(procs, config, db_url), key


STORED = "%\nO01234 (BRACKET OP2)\nG20\nG00 G90 G54 X0. Y0.\nG01 X2.5 F15.\nM30\n%\n"


@on("postgresql")
def test_a_haas_punch_lands_in_the_inbox_under_its_o_number(
    tmp_path: Path, haas: FleetThread, procs: Procs, db_url: str
) -> None:
    sim = haas.fleet.sims["haas-serial-1"]
    haas.call(lambda: sim.control.save_program(STORED))
    client, key = _server(tmp_path, haas, procs, db_url)
    with client:
        haas.fleet.serial_ports["haas-serial-1"].select("punch:O1234")  # the operator's key
        items = wait_for(
            "the punch in the inbox",
            lambda: client.get("/api/inbox", headers=auth(key)).json(),
            describe=lambda: procs.log("server"),
        )
        assert [(i["name"], i["machine"], i["state"]) for i in items] == [
            ("O01234.nc", "haas-serial-1", "new")
        ]
        got = client.get(f"/api/inbox/{items[0]['id']}/content", headers=auth(key)).content
        lines = [line for line in got.decode().splitlines() if line.strip()]
        assert lines == [line for line in STORED.splitlines() if line.strip()]
        detail = client.get(f"/api/inbox/{items[0]['id']}", headers=auth(key)).json()
        assert detail["diff"][0] == "--- (not in library)"
        accepted = client.post(f"/api/inbox/{items[0]['id']}/accept", headers=auth(key), json={})
        assert accepted.status_code == 200, accepted.text
        assert (accepted.json()["program"], accepted.json()["state"]) == ("O01234.nc", "draft")
        assert client.get("/api/inbox", headers=auth(key)).json() == []
    assert (tmp_path / "lib" / "inbox" / "O01234.nc").read_bytes() == got


@on("sqlite")
def test_remote_request_sends_the_program_and_reports_the_missing_one(
    tmp_path: Path, haas: FleetThread, procs: Procs, db_url: str
) -> None:
    sim = haas.fleet.sims["haas-serial-1"]
    request = "%\nO09999 (REQ O1234 REQ O5555)\nM30\n%\n"
    haas.call(lambda: sim.control.save_program(request))
    client, key = _server(tmp_path, haas, procs, db_url)
    library_program = STORED.replace("\n", "\r\n").encode()
    with client:
        assert (
            client.put(
                "/api/programs/O01234.nc", content=library_program, headers=auth(key)
            ).status_code
            == 201
        )
        client.post("/api/programs/O01234.nc/versions/1/release", headers=auth(key))
        port = haas.fleet.serial_ports["haas-serial-1"]
        port.select("punch:O9999")  # send the request ...
        port.select("auto")  # ... then switch to receive, within the request delay

        got = _answer_in_memory(haas, sim, port, procs)
        assert got[1234].split() == STORED.split()
        assert "(O05555.NC NOT IN LIBRARY)" in got[9998]
        assert got[9998].split()[1:3] == ["O09998", "(OPENDNC"]
        audit = client.get(
            "/api/audit", headers=auth(key), params={"action": "program.request"}
        ).json()
        assert len(audit) == 1
        assert audit[0]["detail"]["requested"] == ["O01234.nc", "O05555.nc"]
        assert audit[0]["detail"]["sent"] == ["O01234.nc"]
        assert audit[0]["result"] == "refused"
        # The program went out no sooner than the request delay after the request.
        starts = client.get(
            "/api/audit", headers=auth(key), params={"action": "job.start", "limit": 100}
        ).json()
        asked = datetime.fromisoformat(audit[0]["at"])
        first_start = min(datetime.fromisoformat(r["at"]) for r in starts)
        assert (first_start - asked).total_seconds() >= DELAY
        # The request itself is no inbox item.
        assert client.get("/api/inbox", headers=auth(key)).json() == []


# A typo on line 5: G300 is no G code of a Haas mill (its manual's G-code table).
TYPO = "%\nO02000 (BRACKET OP3)\nG20\nG00 G90 G54 X0. Y0.\nG300 X1.\nM30\n%\n"
# A Heidenhain conversational program stored under an O-number a Haas operator can ask for.
KLARTEXT = (
    "0 BEGIN PGM O03000 MM\n1 BLK FORM 0.1 Z X+0 Y+0 Z-20\n2 BLK FORM 0.2 X+100 Y+100 Z+0\n"
    "3 TOOL CALL 1 Z S2000\n4 L X+0 Y+0 FMAX M3\n5 L X+10 F200\n6 END PGM O03000 MM\n"
)


@on("postgresql")
def test_a_requested_program_that_fails_its_check_is_not_sent_but_reported(
    tmp_path: Path, haas: FleetThread, procs: Procs, db_url: str
) -> None:
    # The same rule as a send from the API: errors for this machine block it (nobody at
    # the control can override them); warnings do not.
    sim = haas.fleet.sims["haas-serial-1"]
    request = "%\nO09999 (REQ O1234 REQ O2000 REQ O3000)\nM30\n%\n"
    haas.call(lambda: sim.control.save_program(request))
    client, key = _server(tmp_path, haas, procs, db_url, check="block")
    with client:
        for name, text in (("O01234.nc", STORED), ("O02000.nc", TYPO), ("O03000.nc", KLARTEXT)):
            put = client.put(f"/api/programs/{name}", content=text.encode(), headers=auth(key))
            assert put.status_code == 201, put.text
            # a request means the released version, as a send without a number does; the
            # release checks the text alone (a typo's error is overridden there, on purpose)
            released = client.post(
                f"/api/programs/{name}/versions/1/release",
                json={"override": "the request's check is under test"},
                headers=auth(key),
            )
            assert released.status_code == 200, released.text
        # STORED feeds with the spindle stopped: a warning, no error, on this machine
        stored = client.get(
            "/api/programs/O01234.nc/versions/1/check",
            headers=auth(key),
            params={"machine": "haas-serial-1"},
        ).json()
        assert (stored["errors"], stored["warnings"] > 0) == (0, True), stored
        port = haas.fleet.serial_ports["haas-serial-1"]
        port.select("punch:O9999")
        port.select("auto")

        got = _answer_in_memory(haas, sim, port, procs)
        assert got[1234].split() == STORED.split()
        report = [line.strip() for line in got[9998].splitlines() if line.strip()]
        assert report[1].startswith("O09998 (OPENDNC REQUEST FAILED"), report
        # each refused program, then the line of its first error and what it is
        typo = report.index("(O02000.NC FAILED ITS CHECK)")
        assert report[typo + 1].startswith("(LINE 5: G300 "), report
        klartext = report.index("(O03000.NC FAILED ITS CHECK)")
        assert report[klartext + 1].startswith("(LINE 1: "), report
        # the family mismatch, however the control's short lines wrap it
        words = " ".join(report[klartext + 1 : klartext + 3]).split()
        words = [w.strip("()") for w in words]
        assert "HEIDENHAIN" in words, report
        assert "HAAS" in words, report

        # The answer is queued in one transaction: only O01234 and the report went out. (The
        # control holds a file a moment before its job is recorded done.)
        def ended() -> list[dict[str, Any]] | None:
            jobs = client.get(
                "/api/jobs", headers=auth(key), params={"machine": "haas-serial-1"}
            ).json()
            return None if any(j["state"] in ("queued", "running") for j in jobs) else jobs

        sent = wait_for("the answer's jobs to end", ended)
        assert sorted((j["kind"], j["program"], j["state"]) for j in sent) == [
            ("report", None, "done"),
            ("send", "O01234.nc", "done"),
        ]
        for number in (2000, 3000):
            assert _read(haas, sim, number) is None
        (row,) = client.get(
            "/api/audit", headers=auth(key), params={"action": "program.request"}
        ).json()
        assert row["result"] == "refused"
        assert row["detail"]["sent"] == ["O01234.nc"]
        assert [r.split(" ")[0] for r in row["detail"]["refused"]] == ["O02000.nc", "O03000.nc"]
        failed = {f["program"]: f for f in row["detail"]["failed_checks"]}
        assert sorted(failed) == ["O02000.nc", "O03000.nc"]
        assert (failed["O02000.nc"]["version"], failed["O02000.nc"]["first"]["line"]) == (1, 5)
        assert "G300" in failed["O02000.nc"]["reason"]
        assert failed["O03000.nc"]["first"]["line"] == 1
        assert all(f["errors"] >= 1 for f in failed.values())


@on("sqlite")
def test_a_rule_that_builds_a_path_is_answered_with_a_failure_report(
    tmp_path: Path, haas: FleetThread, procs: Procs, db_url: str
) -> None:
    # A shop's own rule takes whatever the operator typed; a folder in it is no program name.
    sim = haas.fleet.sims["haas-serial-1"]
    haas.call(lambda: sim.control.save_program("%\nO09999 (SEND ../../etc/passwd)\nM30\n%\n"))
    rule = "[[requests.rules]]\npattern = '\\(SEND\\s+(?P<part>\\S+)\\)'\ntemplate = '{part}'\n"
    client, key = _server(tmp_path, haas, procs, db_url, extra=rule)
    with client:
        port = haas.fleet.serial_ports["haas-serial-1"]
        port.select("punch:O9999")
        port.select("auto")
        report = wait_for(
            "the failure report in the control's memory",
            lambda: _read(haas, sim, 9998),
            describe=lambda: (port.messages, procs.log("server")),
        )
        assert "NOT A PROGRAM NAME" in report
        (row,) = client.get(
            "/api/audit", headers=auth(key), params={"action": "program.request"}
        ).json()
        assert (row["detail"]["requested"], row["detail"]["sent"]) == (["../../etc/passwd"], [])
        assert client.get("/api/programs", headers=auth(key)).json() == []
        assert client.get("/api/inbox", headers=auth(key)).json() == []
    assert not any(tmp_path.rglob("passwd"))


def _answer_in_memory(haas: FleetThread, sim: Any, port: Any, procs: Procs) -> dict[int, str]:
    """The sent program O01234 and the report O09998, once both are in the control's memory."""

    def memory() -> dict[int, str]:
        return {n: text for n in (1234, 9998) if (text := _read(haas, sim, n)) is not None}

    got: dict[int, str] = wait_for(
        "the answer in the control's memory",
        lambda: len(memory()) == 2 and memory(),
        describe=lambda: (port.messages, procs.log("server")),
    )
    return got


def _read(haas: FleetThread, sim: Any, number: int) -> str | None:
    try:
        text: str = haas.call(lambda: sim.control.read_program(number))
    except Exception:
        return None
    return text


MOVES = "".join(f"G01 X{i % 50}.5 Y{i % 7}. F30.\n" for i in range(6000))
LONG = f"%\nO03000 (LONG RUN)\nG20\nT1 M06\nG54\nS1200 M03\n{MOVES}M30\n%\n".encode()


def slow_serial_haas(root: Path) -> FleetThread:
    """One serial Haas that drip-feeds slowly enough to stop ``LONG`` midway."""
    # 1000 blocks a second: LONG's 6,000 lines (about 130 kB, more than the cable and the
    # ptys buffer) run about 6 s; a feed that stops for a second raises the control's DNC
    # link alarm.
    return FleetThread(root, tnc=0, haas=0, serial_haas=1, block_rate=1000, dnc_timeout=1.0)


def interrupt_dripfeed(
    client: httpx.Client, key: str, front: Any
) -> tuple[int, dict[str, Any], int]:
    """Store ``LONG`` as O03000.nc, drip-feed it to haas-serial-1 and cancel the feed well
    under way (``front`` is the control's serial port). Returns the job's id, its row once
    stopped (interrupted) and the line the error says to restart from."""
    client.put("/api/programs/O03000.nc", content=LONG, headers=auth(key))
    # a drip-feed without a version sends the released one, from the API as from the page
    released = client.post("/api/programs/O03000.nc/versions/1/release", headers=auth(key))
    assert released.status_code == 200, released.text
    started = client.post(
        "/api/jobs",
        headers=auth(key),
        json={"kind": "dripfeed", "program": "O03000.nc", "machines": ["haas-serial-1"]},
    )
    assert started.status_code == 201, started.text
    job_id: int = started.json()[0]["id"]
    wait_for("the feed to be well under way", lambda: front.dnc_lines > 300)
    # what the server does to the control is its state: the feed runs the program
    machine = client.get("/api/machines/haas-serial-1", headers=auth(key)).json()
    assert (machine["state"], machine["status"]["program"]) == ("running", "O03000.nc"), machine
    assert client.post(f"/api/jobs/{job_id}/cancel", headers=auth(key)).status_code == 200
    first: dict[str, Any] = wait_for(
        "the feed to stop",
        lambda: (
            (j := client.get(f"/api/jobs/{job_id}", headers=auth(key)).json())["state"] != "running"
            and j
        ),
    )
    assert first["state"] == "interrupted", first
    stopped_at = int(first["error"].rsplit("line ", 1)[1].split(";")[0])
    # a feed a person cancelled leaves a stopped program, not an unknown or a ready machine
    wait_for(
        "the machine stopped",
        lambda: (
            client.get("/api/machines/haas-serial-1", headers=auth(key)).json()["state"]
            == "stopped"
        ),
    )
    return job_id, first, stopped_at


@pytest.fixture
def slow_haas(tmp_path: Path) -> Iterator[FleetThread]:
    fleet = slow_serial_haas(tmp_path / "machines")
    try:
        yield fleet
    finally:
        fleet.stop()


def test_dripfeed_interrupted_then_restarted_from_its_line(
    tmp_path: Path, slow_haas: FleetThread, procs: Procs, db_url: str
) -> None:
    client, key = _server(tmp_path, slow_haas, procs, db_url, dripfeed=True)
    program = LONG
    front = slow_haas.fleet.serial_ports["haas-serial-1"]
    with client:
        wait_for(
            "the machine online",
            lambda: client.get("/api/machines/haas-serial-1", headers=auth(key)).json()["online"],
        )
        job_id, first, stopped_at = interrupt_dripfeed(client, key, front)
        assert "restart from there" in first["error"]
        total = program.count(b"\n")
        assert 300 < stopped_at < total
        # The job keeps what it fed: the program's bytes up to the line it reached.
        before = len(b"".join(program.splitlines(keepends=True)[: stopped_at - 1]))
        through = len(b"".join(program.splitlines(keepends=True)[:stopped_at]))
        assert before <= first["bytes_done"] <= through, (first["bytes_done"], before, through)
        (row,) = [
            r
            for r in client.get(
                "/api/audit", params={"machine": "haas-serial-1"}, headers=auth(key)
            ).json()
            if r["job_id"] == job_id and r["result"] == "interrupted"
        ]
        assert row["bytes"] == first["bytes_done"]
        # The control, starved, raises its DNC link alarm; the operator presses RESET and
        # restarts from the line the server reports.
        wait_for(
            "the control's DNC link alarm", lambda: front.messages, describe=lambda: front.messages
        )
        assert front.messages[-1].startswith("RS232 ABORT DNC link lost"), front.messages
        control = slow_haas.fleet.sims["haas-serial-1"].control
        slow_haas.call(control.reset)
        lines_before, runs_before = front.dnc_lines, len(front.messages)
        # The reported line is the first one the control did not get: the first run began
        # at the program's first block and handed lines_before blocks to the control.
        lines = program.decode().splitlines()
        first_block = next(i for i, line in enumerate(lines) if line == front.dnc_heads[0][0])
        assert first_block + lines_before + 1 == stopped_at, (lines_before, stopped_at)

        again = client.post(
            f"/api/jobs/{job_id}/retry", headers=auth(key), json={"from_line": stopped_at}
        )
        assert again.status_code == 201, again.text
        (done,) = wait_jobs(client, key, [again.json()["id"]])
        assert done["state"] == "done", done["error"]
        assert done["params"]["from_line"] == stopped_at
        # Its bytes are the stored program's from that line on (one definition of progress),
        # not what went over the wire with the preamble and the control's line ends.
        rest = b"".join(program.splitlines(keepends=True)[stopped_at - 1 :])
        assert done["bytes_done"] == len(rest), (done["bytes_done"], len(rest))
        # The second run: the restart preamble, then the program from that line to M30.
        wait_for("the control to finish the run", lambda: len(front.messages) > runs_before)
        assert front.messages[-1] == "RS232 DONE", front.messages
        ran = front.dnc_lines - lines_before
        remaining = total - stopped_at + 1
        assert remaining <= ran <= remaining + 20, (ran, remaining)
        # The second run began with the preamble that restores the program's modal state
        # (units, tool, work offset, spindle), then went on at the reported line itself.
        head = front.dnc_heads[-1]
        # ``remaining`` counts the closing %, which is no block.
        fed_from_the_program = remaining - 1
        preamble = head[: ran - fed_from_the_program]
        assert f"(OPENDNC RESTART AT LINE {stopped_at})" in preamble, head
        for block in ("G20", "T1 M06", "G54", "S1200 M03"):
            assert block in preamble, (block, head)
        assert head[len(preamble) : len(preamble) + 3] == lines[stopped_at - 1 : stopped_at + 2]
