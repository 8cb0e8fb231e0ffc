"""The DNC server end to end: every process (server, virtual controls, cable) started here.

One released program goes to four machines (two virtual TNCs over LSV2, a virtual Haas on a
virtual RS-232 cable by XModem, a virtual Haas NGC through its share) and must arrive
byte-identical everywhere, with audit rows; the same suite runs on SQLite and PostgreSQL.
"""

from __future__ import annotations

import hashlib
import json
import signal
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from tests.server.conftest import on
from tests.server.harness import (
    DEADLINE,
    Procs,
    auth,
    create_key,
    free_port,
    httpx,
    listening,
    start_server,
    wait_for,
    wait_jobs,
)

# CRLF line ends: what the TNC stores for a text file, and what Setting 25 = CR LF gives.
PROGRAM = b"%\r\nO01234 (BRACKET)\r\nG20\r\nG00 G90 G54 X0. Y0.\r\nG01 X1.5 F20.\r\nM30\r\n%\r\n"
# PROGRAM with 3,000 more moves before its M30: several seconds by XModem at 115200 baud.
BIG = PROGRAM[:-5] + b"".join(b"G01 X%d.5 Y1. F20.\r\n" % i for i in range(3000)) + PROGRAM[-5:]


class Shop:
    """The virtual shop: four machines and the server's configuration."""

    def __init__(self, tmp: Path, procs: Procs, db_url: str) -> None:
        self.tmp, self.procs, self.db_url = tmp, procs, db_url
        self.tnc_ports = [free_port(), free_port()]
        self.tnc_roots = [tmp / "tnc-a", tmp / "tnc-b"]
        self.mdc_port = free_port()
        self.haas_mem = tmp / "haas-mem"
        self.ngc_mem = tmp / "ngc-mem"
        self.ngc_share = tmp / "ngc-share"
        self.cable_pc = tmp / "pc"
        self.cable_haas = tmp / "haas"
        self.config = tmp / "shop.toml"
        for folder in (*self.tnc_roots, self.haas_mem, self.ngc_mem, self.ngc_share):
            folder.mkdir()

    def start_machines(self) -> None:
        for i, (port, root) in enumerate(zip(self.tnc_ports, self.tnc_roots, strict=True)):
            self.start_tnc(i, port, root)
        self.procs.start(
            "cable",
            "sim",
            "cable",
            "--baud",
            "115200",
            "--link-a",
            str(self.cable_haas),
            "--link-b",
            str(self.cable_pc),
        )
        wait_for("the cable", lambda: self.cable_haas.exists() and self.cable_pc.exists())
        self.start_serial_haas()
        self.procs.start(
            "ngc", "sim", "haas", "--root", str(self.ngc_mem), "--mdc-port", str(self.mdc_port)
        )
        for port in (*self.tnc_ports, self.mdc_port):
            wait_for(f"port {port}", listening(port))

    def start_serial_haas(self) -> None:
        self.procs.start(
            "haas",
            "sim",
            "haas",
            "--serial",
            str(self.cable_haas),
            "--baud",
            "115200",
            "--serial-mode",
            "receive",
            "--root",
            str(self.haas_mem),
            "--mdc-port",
            "0",  # not used here; the system's pick cannot collide with another test port
        )

    def start_tnc(self, i: int, port: int, root: Path, *extra: str) -> None:
        self.procs.start(
            f"tnc{i}",
            "sim",
            "tnc",
            "--profile",
            "tnc640",
            "--port",
            str(port),
            "--root",
            str(root),
            *extra,
        )

    def write_config(self) -> None:
        a, b = self.tnc_ports
        self.config.write_text(
            f"""
[server]
name = "dnc-test"

[library]
path = "programs"
check = "warn"  # transport payloads; the program check has its own tests

[[machines]]
name = "tnc-a"
kind = "lsv2"
host = "127.0.0.1"
port = {a}
poll_interval = 0.2

[[machines]]
name = "tnc-b"
kind = "lsv2"
host = "127.0.0.1"
port = {b}
released_only = true
poll_interval = 0.2

[[machines]]
name = "vf2-serial"
kind = "haas_serial"
serial = "{self.cable_pc}"
serial_profile = {{ baud = 115200, eob = "CRLF" }}

[[machines]]
name = "vf4-ngc"
kind = "haas_ngc"
host = "127.0.0.1"
mdc_port = {self.mdc_port}
share = "{self.ngc_share}"
poll_interval = 0.2
"""
        )

    def key(self, role: str, *, cli: bool = False) -> str:
        return create_key(self.config, self.db_url, role, user=f"{role}-1", cli=cli)

    def start_server(self) -> httpx.Client:
        return start_server(self.procs, self.config, self.db_url)


@pytest.fixture
def shop(tmp_path: Path, procs: Procs, db_url: str) -> Shop:
    s = Shop(tmp_path, procs, db_url)
    s.start_machines()
    s.write_config()
    return s


def test_released_program_reaches_four_machines_byte_identical(shop: Shop, procs: Procs) -> None:
    admin = shop.key("admin", cli=True)  # as an admin makes it (the others: the same calls)
    viewer = shop.key("viewer")
    with shop.start_server() as client:
        # Every machine comes online.
        def machines() -> list[Any]:
            listed = client.get("/api/machines", headers=auth(viewer)).json()
            return [(m["name"], m["online"], m["last_error"]) for m in listed]

        wait_for("all machines online", lambda: all(m[1] for m in machines()), describe=machines)

        up = client.put(
            "/api/programs/O01234.nc",
            content=PROGRAM,
            headers=auth(admin),
            params={"comment": "first cut"},
        )
        assert up.status_code == 201, up.text
        assert up.json()["sha256"] == hashlib.sha256(PROGRAM).hexdigest()

        # A draft goes to the machine that takes drafts; the released-only machine refuses
        # it, named with its reason in the answer's header (and the audit trail).
        draft = client.post(
            "/api/jobs",
            headers=auth(admin),
            json={"program": "O01234.nc", "version": 1, "machines": ["tnc-a", "tnc-b"]},
        )
        assert draft.status_code == 201, draft.text
        assert [j["machine"] for j in draft.json()] == ["tnc-a"]
        (refused,) = json.loads(draft.headers["OpenDNC-Refused"])
        assert refused["machine"] == "tnc-b"
        assert "released programs only" in refused["reason"]
        (early,) = wait_jobs(client, admin, [draft.json()[0]["id"]])
        assert early["state"] == "done", early["error"]
        # the released-only machine alone: refused (409), nothing queued
        alone = client.post(
            "/api/jobs",
            headers=auth(admin),
            json={"program": "O01234.nc", "version": 1, "machines": ["tnc-b"]},
        )
        assert alone.status_code == 409
        assert "released programs only" in alone.json()["detail"]
        assert len(client.get("/api/jobs", headers=auth(admin)).json()) == 1

        rel = client.post("/api/programs/O01234.nc/versions/1/release", headers=auth(admin))
        assert rel.status_code == 200
        assert rel.json()["state"] == "released"
        sent = client.post(
            "/api/jobs",
            headers=auth(admin),
            json={"program": "O01234.nc", "machines": ["tnc-a", "tnc-b", "vf2-serial", "vf4-ngc"]},
        )
        assert sent.status_code == 201, sent.text
        jobs = wait_jobs(client, admin, [j["id"] for j in sent.json()])
        assert [j["state"] for j in jobs] == ["done"] * 4, [j["error"] for j in jobs]

        audit = client.get("/api/audit", headers=auth(viewer), params={"action": "job.send"})
        rows = {r["machine"]: r for r in audit.json()}
        assert set(rows) == {"tnc-a", "tnc-b", "vf2-serial", "vf4-ngc"}
        for row in rows.values():
            assert row["result"] == "ok"
            assert row["sha256"] == hashlib.sha256(PROGRAM).hexdigest()
            assert row["bytes"] == len(PROGRAM)
            assert row["detail"]["by"] == "admin-1"
        # what each load's outcome says about its check (issue 20, item 6)
        notes = {name: row["detail"]["verification"] for name, row in rows.items()}
        assert notes == {
            "tnc-a": "verified",
            "tnc-b": "verified",
            "vf4-ngc": "verified",
            "vf2-serial": "not verified (checksum mode only)",
        }
        assert rows["vf2-serial"]["detail"]["verified"] is None

    for root in shop.tnc_roots:
        assert (root / "TNC" / "nc_prog" / "O01234.nc").read_bytes() == PROGRAM
    assert (shop.ngc_share / "O01234.nc").read_bytes() == PROGRAM
    received = wait_for(
        "the serial Haas to store the program", lambda: list(shop.haas_mem.iterdir())
    )
    assert [p.name for p in received] == ["O01234.nc"], procs.log("haas")
    assert received[0].read_bytes().replace(b"\r\n", b"\n") == PROGRAM.replace(b"\r\n", b"\n")


@on("sqlite")
def test_api_refuses_missing_keys_low_roles_and_bad_names(shop: Shop) -> None:
    viewer = shop.key("viewer")
    operator = shop.key("operator")
    with shop.start_server() as client:
        health = client.get("/api/health").json()
        assert (health["status"], health["database"]["ok"]) == ("ok", True)
        assert health["leases"]["mode"] == "single"
        assert client.get("/api/machines").status_code == 401
        assert client.put("/api/programs/O1.nc", content=PROGRAM).status_code == 401
        bad_key = auth("odk_" + "x" * 43)
        assert client.get("/api/machines", headers=bad_key).status_code == 401
        assert (
            client.put("/api/programs/O1.nc", content=PROGRAM, headers=auth(viewer)).status_code
            == 403
        )
        assert (
            client.put("/api/programs/O1.nc", content=PROGRAM, headers=auth(operator)).status_code
            == 403
        )
        key = client.post("/api/keys", headers=auth(operator), json={"user": "x", "role": "admin"})
        assert key.status_code == 403
        programmer = shop.key("programmer")
        codes = []
        for name in ("..%2F..%2Fetc%2Fpasswd", "a%5Cb", "%2Ehidden", "CON", "x" * 101, "O1%0A"):
            r = client.put(f"/api/programs/{name}", content=PROGRAM, headers=auth(programmer))
            codes.append((name, r.status_code))
        # a folder in the name matches no route: 404, saying names hold no folders
        assert codes[0] == ("..%2F..%2Fetc%2Fpasswd", 404), codes
        assert all(code == 400 for _, code in codes[1:]), codes
        assert client.get("/api/programs", headers=auth(viewer)).json() == []
        versions = client.get(
            "/api/audit", headers=auth(viewer), params={"action": "program.version"}
        )
        assert versions.json() == []
        openapi = client.get("/openapi.json").json()
        assert {"/api/machines", "/api/programs", "/api/jobs", "/api/audit"} <= set(
            openapi["paths"]
        )
    assert not any(shop.tmp.rglob("passwd"))
    library = shop.tmp / "programs"
    assert not library.exists() or not any(p.is_file() for p in library.rglob("*"))


@on("postgresql")
def test_killed_machine_retries_its_job_when_it_returns(shop: Shop, procs: Procs) -> None:
    admin = shop.key("admin")
    procs.stop("tnc1", signal.SIGKILL)  # tnc-b is away when the job is queued
    with shop.start_server() as client:
        assert (
            client.put("/api/programs/O01234.nc", content=PROGRAM, headers=auth(admin)).status_code
            == 201
        )
        client.post("/api/programs/O01234.nc/versions/1/release", headers=auth(admin))
        sent = client.post(
            "/api/jobs", headers=auth(admin), json={"program": "O01234.nc", "machines": ["tnc-b"]}
        )
        job_id = sent.json()[0]["id"]
        machine = wait_for(
            "the server to find tnc-b away",
            lambda: (
                (m := client.get("/api/machines/tnc-b", headers=auth(admin)).json())
                and m["last_error"]
                and m
            ),
        )
        assert machine["online"] is False
        assert client.get(f"/api/jobs/{job_id}", headers=auth(admin)).json()["state"] == "queued"
        shop.start_tnc(1, shop.tnc_ports[1], shop.tnc_roots[1])
        (job,) = wait_jobs(client, admin, [job_id])
        assert job["state"] == "done", job["error"]
    target = shop.tnc_roots[1] / "TNC" / "nc_prog"
    assert (target / "O01234.nc").read_bytes() == PROGRAM
    assert [p.name for p in target.iterdir() if "O01234" in p.name] == ["O01234.nc"]


def _send_until_under_way(
    client: httpx.Client, admin: str, body: dict[str, Any], size: int, timeout: float = DEADLINE
) -> tuple[int, Callable[[], dict[str, Any]]]:
    """Queue the send job ``body`` names (one machine) and wait until it has moved some but
    not half of the program's ``size`` bytes. Returns its id and a reader of its row."""
    sent = client.post("/api/jobs", headers=auth(admin), json=body)
    job_id: int = sent.json()[0]["id"]

    def job() -> dict[str, Any]:
        got: dict[str, Any] = client.get(f"/api/jobs/{job_id}", headers=auth(admin)).json()
        return got

    wait_for(
        "the load to be under way",
        lambda: job()["state"] == "running" and 0 < job()["bytes_done"] < size // 2,
        timeout,
        describe=job,
    )
    return job_id, job


@on("postgresql")  # a protocol's retry through the server: one backend is enough
def test_machine_killed_mid_transfer_retries_and_leaves_no_partial_program(
    shop: Shop, procs: Procs
) -> None:
    # The serial Haas dies while the XModem load is on the line (a 3,000-line program takes
    # several seconds at 115200 baud), then comes back on the same cable.
    admin = shop.key("admin")
    with shop.start_server() as client:
        client.put("/api/programs/O01234.nc", content=BIG, headers=auth(admin))
        client.post("/api/programs/O01234.nc/versions/1/release", headers=auth(admin))
        job_id, _job = _send_until_under_way(
            client, admin, {"program": "O01234.nc", "machines": ["vf2-serial"]}, len(BIG)
        )
        procs.stop("haas", signal.SIGKILL)
        assert list(shop.haas_mem.iterdir()) == []  # the dead control kept nothing
        # The operator restarts the control and selects receive again. The server cannot see a
        # dead RS-232 peer: its sender meets the fresh receiver mid-file, gives that attempt
        # up and sends the whole program again.
        shop.start_serial_haas()
        (done,) = wait_jobs(client, admin, [job_id])
        assert done["state"] == "done", done["error"]
        assert done["attempts"] == 2
        rows = client.get(
            "/api/audit", headers=auth(admin), params={"action": "job.send", "limit": 100}
        ).json()
        assert sorted(r["result"] for r in rows if r["job_id"] == job_id) == ["ok", "retry"]
    received = wait_for("the Haas to store the program", lambda: list(shop.haas_mem.iterdir()))
    assert [p.name for p in received] == ["O01234.nc"], procs.log("haas")
    assert received[0].read_bytes().replace(b"\r\n", b"\n") == BIG.replace(b"\r\n", b"\n")
    # Nothing half-written on the server's side either: the library holds the one program.
    library = shop.tmp / "programs"
    assert [p.name for p in library.rglob("*") if p.is_file()] in ([], ["O01234.nc"])


@on("sqlite")
def test_tnc_killed_mid_load_keeps_no_partial_program_and_gets_it_again(
    shop: Shop, procs: Procs
) -> None:
    # LSV2 over TCP: the server sees the connection drop at once and retries once the
    # control is back. The control answers every telegram 10 ms late (a loaded control on a
    # slow network), so a 400 kB program is on the wire for a few seconds.
    procs.stop("tnc0")
    shop.start_tnc(0, shop.tnc_ports[0], shop.tnc_roots[0], "--latency", "10")
    wait_for("the slow TNC", listening(shop.tnc_ports[0]))
    admin = shop.key("admin")
    moves = b"".join(b"L X+%d.5 Y+1 R0 F200\r\n" % i for i in range(18_000))
    big = b"0 BEGIN PGM BIG MM\r\n" + moves + b"99999 END PGM BIG MM\r\n"
    with shop.start_server() as client:
        put = client.put("/api/programs/BIG.H", content=big, headers=auth(admin))
        assert put.status_code == 201, put.text
        job_id, job = _send_until_under_way(
            client,
            admin,
            {"program": "BIG.H", "version": 1, "machines": ["tnc-a"]},
            len(big),
            timeout=120,
        )
        procs.stop("tnc0", signal.SIGKILL)
        target = shop.tnc_roots[0] / "TNC" / "nc_prog"
        assert not (target / "BIG.H").exists()  # never on the control's drive half-written
        wait_for(
            "the job to be queued again",
            lambda: (j := job())["attempts"] == 1 and j["state"] == "queued" and j,
            describe=job,
        )
        shop.start_tnc(0, shop.tnc_ports[0], shop.tnc_roots[0])
        (done,) = wait_jobs(client, admin, [job_id])
        assert done["state"] == "done", done["error"]
        assert done["attempts"] == 2
    assert (target / "BIG.H").read_bytes() == big
    assert [p.name for p in target.iterdir() if "BIG" in p.name.upper()] == ["BIG.H"]
    # The upload the dead control was holding is gone: the control drops it when it starts.
    assert list((shop.tnc_roots[0] / ".partial").iterdir()) == []


def test_server_killed_mid_queue_loses_no_job_and_runs_none_twice(shop: Shop, procs: Procs) -> None:
    admin = shop.key("admin")
    with shop.start_server() as client:
        client.put("/api/programs/O01234.nc", content=BIG, headers=auth(admin))
        client.post("/api/programs/O01234.nc/versions/1/release", headers=auth(admin))
        ids = []
        for _ in range(3):
            sent = client.post(
                "/api/jobs",
                headers=auth(admin),
                json={"program": "O01234.nc", "machines": ["vf2-serial"]},
            )
            ids.append(sent.json()[0]["id"])
        # Kill the server while the first XModem transfer is on the line.
        wait_for(
            "the first job to run",
            lambda: (
                client.get(f"/api/jobs/{ids[0]}", headers=auth(admin)).json()["state"] == "running"
            ),
        )
    procs.stop("server", signal.SIGKILL)
    clustered = shop.db_url.startswith("postgresql")
    with shop.start_server() as client:
        if clustered:
            # On PostgreSQL the server is a cluster of one (docs/server.md#several-servers):
            # taking its machine's lease again, it queues the cut load again, once.
            (first, *rest) = wait_jobs(client, admin, ids)
            assert first["state"] == "done", first
        else:
            first = client.get(f"/api/jobs/{ids[0]}", headers=auth(admin)).json()
            assert first["state"] == "interrupted"
            assert "server stopped" in first["error"]
            rest = wait_jobs(client, admin, ids[1:])
        assert [j["state"] for j in rest] == ["done", "done"]

        def audited(action: str) -> list[dict[str, Any]]:
            rows: list[dict[str, Any]] = client.get(
                "/api/audit", headers=auth(admin), params={"action": action, "limit": 100}
            ).json()
            return rows

        starts, endings = audited("job.start"), audited("job.send")
        takeovers = audited("job.takeover") if clustered else []
        assert [r["job_id"] for r in takeovers] == ([ids[0]] if clustered else [])
        for i in ids:
            # The promise is "none run twice": each job's load completed at most once (the cut
            # one on SQLite never), whatever a loaded machine made it retry on the way.
            completed = [r for r in endings if r["job_id"] == i and r["result"] == "ok"]
            assert len(completed) == (0 if i == ids[0] and not clustered else 1), endings
            # Every claim after the first answers a reason the audit names: a failed attempt
            # queued again ("retry") or the takeover of a cut one; no claim comes from nowhere.
            retries = sum(1 for r in endings if r["job_id"] == i and r["result"] == "retry")
            taken = sum(1 for r in takeovers if r["job_id"] == i)
            claims = sum(1 for r in starts if r["job_id"] == i)
            assert claims == 1 + retries + taken, (i, starts, endings, takeovers)
            job = client.get(f"/api/jobs/{i}", headers=auth(admin)).json()
            assert job["attempts"] == claims, job


def _changed_lines(client: httpx.Client, admin: str, a: int, b: int) -> list[str]:
    """The + and - lines of the API's diff of O01234.nc from version ``a`` to ``b``."""
    diff = client.get(
        "/api/programs/O01234.nc/diff", headers=auth(admin), params={"a": a, "b": b}
    ).json()["lines"]
    return [line.rstrip("\r\n") for line in diff if line[:1] in "+-"]


@on("postgresql")
def test_diff_between_versions_and_a_reordered_cancelled_queue(shop: Shop, procs: Procs) -> None:
    admin = shop.key("admin")
    second = PROGRAM.replace(b"G01 X1.5 F20.", b"G01 X2.5 F15.")
    procs.stop("tnc0", signal.SIGKILL)  # tnc-a's queue waits while the operator rearranges it
    with shop.start_server() as client:
        for content in (PROGRAM, second, PROGRAM.replace(b"BRACKET", b"BRACKET OP3")):
            put = client.put("/api/programs/O01234.nc", content=content, headers=auth(admin))
            assert put.status_code == 201, put.text
        changed = _changed_lines(client, admin, 1, 2)
        assert "-G01 X1.5 F20." in changed
        assert "+G01 X2.5 F15." in changed
        assert not any("BRACKET" in line for line in changed)
        changed13 = _changed_lines(client, admin, 3, 1)
        assert "-O01234 (BRACKET OP3)" in changed13
        assert "+O01234 (BRACKET)" in changed13
        assert not any("X1.5" in line for line in changed13)

        ids = []
        for number in (1, 2, 3):
            sent = client.post(
                "/api/jobs",
                headers=auth(admin),
                json={"program": "O01234.nc", "version": number, "machines": ["tnc-a"]},
            )
            ids.append(sent.json()[0]["id"])
        first, middle, last = ids
        moved = client.post(f"/api/jobs/{last}/move", headers=auth(admin), json={"index": 0})
        assert moved.status_code == 200, moved.text
        assert client.post(f"/api/jobs/{middle}/cancel", headers=auth(admin)).status_code == 200
        queued = client.get(
            "/api/jobs", headers=auth(admin), params={"machine": "tnc-a", "state": "queued"}
        ).json()
        assert [j["id"] for j in queued] == [last, first]
        shop.start_tnc(0, shop.tnc_ports[0], shop.tnc_roots[0])
        done = wait_jobs(client, admin, [last, first])
        assert [j["state"] for j in done] == ["done", "done"], [j["error"] for j in done]
        starts = client.get(
            "/api/audit",
            headers=auth(admin),
            params={"action": "job.start", "machine": "tnc-a", "limit": 100},
        ).json()
        # Newest first: the moved job ran first, the cancelled one never.
        assert [r["job_id"] for r in reversed(starts)] == [last, first]
        cancelled = client.get(f"/api/jobs/{middle}", headers=auth(admin)).json()
        assert (cancelled["state"], cancelled["started"]) == ("cancelled", None)
    # The job that ran last (version 1) is what the control holds.
    assert (shop.tnc_roots[0] / "TNC" / "nc_prog" / "O01234.nc").read_bytes() == PROGRAM


@on("sqlite")
def test_receive_backup_and_delete_jobs_on_a_tnc(shop: Shop) -> None:
    admin = shop.key("admin")
    operator = shop.key("operator")
    with shop.start_server() as client:
        client.put("/api/programs/O01234.nc", content=PROGRAM, headers=auth(admin))
        sent = client.post(
            "/api/jobs",
            headers=auth(admin),
            json={"program": "O01234.nc", "version": 1, "machines": ["tnc-a"]},
        )
        wait_jobs(client, admin, [sent.json()[0]["id"]])
        path = "TNC:/nc_prog/O01234.nc"

        def job(kind: str, machine: str, key: str = admin, where: str = path) -> Any:
            return client.post(
                "/api/jobs",
                headers=auth(key),
                json={"kind": kind, "path": where, "machines": [machine]},
            )

        received = wait_jobs(client, admin, [job("receive", "tnc-a").json()[0]["id"]])
        assert received[0]["state"] == "done", received[0]["error"]
        (item,) = client.get("/api/inbox", headers=auth(admin)).json()
        assert (item["name"], item["machine"]) == ("O01234.nc", "tnc-a")
        content = client.get(f"/api/inbox/{item['id']}/content", headers=auth(admin)).content
        assert content == PROGRAM

        backup = job("backup", "tnc-a", where="TNC:/nc_prog")
        (done,) = wait_jobs(client, admin, [backup.json()[0]["id"]])
        assert done["state"] == "done", done["error"]
        rows = client.get("/api/audit", headers=auth(admin), params={"action": "job.backup"})
        assert rows.json()[0]["detail"]["copied"] >= 1

        assert job("delete", "tnc-a", operator).status_code == 403
        deleted = wait_jobs(client, admin, [job("delete", "tnc-a").json()[0]["id"]])
        assert deleted[0]["state"] == "done", deleted[0]["error"]
        refused = wait_jobs(client, admin, [job("delete", "vf2-serial").json()[0]["id"]])
        assert refused[0]["state"] == "failed"
        assert refused[0]["attempts"] == 1  # a refusal is not retried
        assert "RS-232 cannot delete" in refused[0]["error"]
    assert not (shop.tnc_roots[0] / "TNC" / "nc_prog" / "O01234.nc").exists()
    assert (shop.tmp / "backups" / "tnc-a" / "O01234.nc").read_bytes() == PROGRAM


@on("sqlite")  # a protocol through the server: one backend is enough
def test_a_heidenhain_on_rs232_gets_its_program(tmp_path: Path, procs: Procs, db_url: str) -> None:
    # A TNC without a network: LSV2 over a virtual RS-232 cable, 8E1 as the controls default to.
    pc, tnc = tmp_path / "pc", tmp_path / "tnc-port"
    root = tmp_path / "tnc-root"
    procs.start(
        "cable",
        "sim",
        "cable",
        "--baud",
        "115200",
        "--bits-per-char",
        "11",
        "--link-a",
        str(tnc),
        "--link-b",
        str(pc),
    )
    wait_for("the cable", lambda: tnc.exists() and pc.exists())
    procs.start(
        "tnc",
        "sim",
        "tnc",
        "--profile",
        "itnc530",
        "--root",
        str(root),
        "--serial",
        str(tnc),
        "--baud",
        "115200",
        "--no-tcp",
    )
    wait_for("the virtual TNC on its serial line", lambda: "listening" in procs.log("tnc"))
    config = tmp_path / "shop.toml"
    config.write_text(f"""
[library]
check = "warn"  # a Haas program as the transport payload; the program check has its own tests

[[machines]]
name = "tnc-serial"
kind = "lsv2"
serial = "{pc}"
serial_profile = {{ baud = 115200 }}
folder = "TNC:/nc_prog"
poll_interval = 0.5
""")
    key = create_key(config, db_url)
    with start_server(procs, config, db_url) as client:
        wait_for(
            "the machine online",
            lambda: client.get("/api/machines/tnc-serial", headers=auth(key)).json()["online"],
            describe=lambda: procs.log("server"),
        )
        client.put("/api/programs/O01234.nc", content=PROGRAM, headers=auth(key))
        sent = client.post(
            "/api/jobs",
            headers=auth(key),
            json={"program": "O01234.nc", "version": 1, "machines": ["tnc-serial"]},
        )
        (job,) = wait_jobs(client, key, [sent.json()[0]["id"]])
        assert job["state"] == "done", job["error"]
    assert (root / "TNC" / "nc_prog" / "O01234.nc").read_bytes() == PROGRAM
