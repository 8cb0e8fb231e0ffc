"""The library's program check: run on save, kept per version, read by the API, and enforced
on release and send (errors block unless a programmer overrides with a reason, audited).

The programs are written here with their defects on known lines; the expected lines and
messages come from the defects, not from a run of the checker."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import func, select

from opendnc.nccheck import MachineLimits
from opendnc.server.jobs import queue as jobs
from opendnc.server.library import checks as program_checks
from opendnc.server.store.models import AuditEntry, JobState, Role, VersionCheck
from tests.server.inprocess_app import App, running

CLEAN = b"%\nO01000 (CLEAN)\nT1 M06\nG00 G90 G54 X0. Y0.\nS1000 M03\nG01 X5. F100.\nM30\n%\n"
# line 4: a G code no Haas has; no other defect
BAD = b"%\nO01001 (BAD)\nT1 M06\nG00 G90 G54 X0. Y0. G999\nM30\n%\n"
# line 4: X-40 in machine coordinates, beyond the X travel [-30, 0] configured below
FAR = b"%\nO01002 (FAR)\nT1 M06\nG53 G00 X-40.\nM30\n%\n"
# line 2: a program number Haas keeps for its own macros
PROTECTED = b"%\nO09000 (MINE)\nG00 G90 G54 X0. Y0.\nM30\n%\n"
KLARTEXT = b"0 BEGIN PGM K MM\n1 L X+0 R0 FMAX\n2 END PGM K MM\n"

MACHINES: list[dict[str, object]] = [
    {"name": "tnc", "kind": "lsv2", "host": "127.0.0.1", "port": 1},
    {
        "name": "haas",
        "kind": "haas_serial",
        "serial": "socket://127.0.0.1:1",
        "travel": {"x": [-30.0, 0.0], "y": [-16.0, 0.0], "z": [-20.0, 0.0]},
    },
    {
        "name": "haas2",
        "kind": "haas_serial",
        "serial": "socket://127.0.0.1:1",
        "travel": {"x": [-30.0, 0.0], "y": [-16.0, 0.0], "z": [-20.0, 0.0]},
    },
]


@pytest.fixture(scope="module")
def app(tmp_path_factory: pytest.TempPathFactory) -> Iterator[App]:
    with running(tmp_path_factory.mktemp("checks"), MACHINES) as served:
        yield served


def _put(app: App, name: str, data: bytes, role: Role = Role.PROGRAMMER) -> dict[str, Any]:
    reply = app.client.put(f"/api/programs/{name}", content=data, headers=app.api(role))
    assert reply.status_code == 201, reply.text
    body: dict[str, Any] = reply.json()
    return body


def _check(app: App, name: str, number: int, machine: str | None = None) -> dict[str, Any]:
    params = {"machine": machine} if machine else {}
    reply = app.client.get(
        f"/api/programs/{name}/versions/{number}/check",
        params=params,
        headers=app.api(Role.VIEWER),
    )
    assert reply.status_code == 200, reply.text
    body: dict[str, Any] = reply.json()
    return body


def _lines(check: dict[str, Any], severity: str = "error") -> list[int]:
    return [p["line"] for p in check["problems"] if p["severity"] == severity]


def _overrides(app: App, program: str) -> list[AuditEntry]:
    with app.server.sessions() as s:
        stmt = select(AuditEntry).where(
            AuditEntry.action == "program.check_override", AuditEntry.program == program
        )
        return list(s.scalars(stmt))


def _check_rows(app: App) -> int:
    with app.server.sessions() as s:
        return int(s.scalar(select(func.count()).select_from(VersionCheck)) or 0)


def test_an_upload_is_checked_on_save_and_the_check_is_kept(app: App) -> None:
    clean = _put(app, "O01000.nc", CLEAN)
    assert clean["check"]["ok"] is True
    assert clean["check"]["errors"] == 0
    assert clean["check"]["control"] == "haas"
    bad = _put(app, "O01001.nc", BAD)
    assert bad["check"]["ok"] is False
    assert _lines(bad["check"]) == [4]
    assert "G999" in bad["check"]["problems"][0]["message"]
    # the API reads the kept check: asking again runs nothing new
    rows = _check_rows(app)
    again = _check(app, "O01001.nc", 1)
    assert again["problems"] == bad["check"]["problems"]
    assert again["checked"] == bad["check"]["checked"]
    assert _check_rows(app) == rows


def test_a_check_against_a_machine_has_its_family_travel_and_protected_numbers(
    app: App,
) -> None:
    _put(app, "O01000.nc", CLEAN)
    on_tnc = _check(app, "O01000.nc", 1, "tnc")
    assert on_tnc["machine"] == "tnc"
    assert not on_tnc["ok"]
    assert _lines(on_tnc) == [1]
    assert "haas program cannot run" in on_tnc["problems"][0]["message"]
    assert _check(app, "O01000.nc", 1, "haas")["ok"] is True
    _put(app, "K.H", KLARTEXT)
    assert _check(app, "K.H", 1, "tnc")["ok"] is True
    assert _lines(_check(app, "K.H", 1, "haas")) == [1]

    _put(app, "O01002.nc", FAR)
    assert _check(app, "O01002.nc", 1)["ok"] is True  # the text alone knows no travel
    far = _check(app, "O01002.nc", 1, "haas")
    assert _lines(far) == [4]
    assert "travel" in far["problems"][0]["message"]

    _put(app, "O09000.nc", PROTECTED)
    mine = _check(app, "O09000.nc", 1, "haas")
    assert _lines(mine) == [2]
    assert "protected program number" in mine["problems"][0]["message"]


def test_machines_alike_share_one_kept_check(app: App) -> None:
    _put(app, "O01002.nc", FAR)
    _check(app, "O01002.nc", 1, "haas")
    rows = _check_rows(app)
    assert _lines(_check(app, "O01002.nc", 1, "haas2")) == [4]
    assert _check_rows(app) == rows


def test_unknown_machine_version_and_program_are_404(app: App) -> None:
    _put(app, "O01000.nc", CLEAN)
    for url, params in [
        ("/api/programs/O01000.nc/versions/1/check", {"machine": "nope"}),
        ("/api/programs/O01000.nc/versions/99/check", {}),
        ("/api/programs/NONE.nc/versions/1/check", {}),
    ]:
        reply = app.client.get(url, params=params, headers=app.api(Role.VIEWER))
        assert reply.status_code == 404, reply.text


def _send(app: App, role: Role, program: str, machine: str, **extra: Any) -> Any:
    body = {"program": program, "version": 1, "machines": [machine], **extra}
    return app.client.post("/api/jobs", json=body, headers=app.api(role))


def test_errors_block_a_send_unless_a_programmer_overrides_with_a_reason(app: App) -> None:
    _put(app, "O01000.nc", CLEAN)
    refused = _send(app, Role.OPERATOR, "O01000.nc", "tnc")
    assert refused.status_code == 409, refused.text
    message = refused.json()["detail"]
    assert "O01000.nc v1 to tnc" in message
    assert "line 1" in message
    assert "haas program cannot run" in message
    # an operator may not override; a programmer must give a reason
    reason = "probing macro, checked by hand"
    assert _send(app, Role.OPERATOR, "O01000.nc", "tnc", override=reason).status_code == 403
    blank = _send(app, Role.PROGRAMMER, "O01000.nc", "tnc", override="  ")
    assert blank.status_code == 400
    assert "reason" in blank.json()["detail"]
    before = len(_overrides(app, "O01000.nc"))
    sent = _send(app, Role.PROGRAMMER, "O01000.nc", "tnc", override=reason)
    assert sent.status_code == 201, sent.text
    job = sent.json()[0]
    assert job["params"]["check_override"] == reason
    rows = _overrides(app, "O01000.nc")
    assert len(rows) == before + 1
    row = rows[-1]
    assert (row.actor, row.machine, row.job_id) == ("programmer", "tnc", job["id"])
    assert row.detail["reason"] == reason
    assert row.detail["errors"] == 1
    assert row.detail["first"]["line"] == 1
    # a clean send needs no override and records none
    assert _send(app, Role.OPERATOR, "O01000.nc", "haas").status_code == 201
    assert len(_overrides(app, "O01000.nc")) == before + 1


def test_a_send_to_several_machines_is_all_or_nothing(app: App) -> None:
    _put(app, "O01002.nc", FAR)
    body = {"program": "O01002.nc", "version": 1, "machines": ["tnc", "haas"]}
    with app.server.sessions() as s:
        queued = len(jobs.list_jobs(s, machine="haas"))
    reply = app.client.post("/api/jobs", json=body, headers=app.api(Role.ADMIN))
    assert reply.status_code == 409
    with app.server.sessions() as s:
        assert len(jobs.list_jobs(s, machine="haas")) == queued


def test_a_retry_keeps_the_jobs_override(app: App) -> None:
    _put(app, "O01000.nc", CLEAN)
    sent = _send(app, Role.PROGRAMMER, "O01000.nc", "tnc", override="on purpose")
    job_id = sent.json()[0]["id"]
    with app.server.sessions.begin() as s:
        job = jobs.get_job(s, job_id)
        job.state = JobState.FAILED
    retried = app.client.post(f"/api/jobs/{job_id}/retry", headers=app.api(Role.OPERATOR))
    assert retried.status_code == 201, retried.text
    assert retried.json()["params"]["check_override"] == "on purpose"


def test_errors_block_a_release_unless_overridden(app: App) -> None:
    _put(app, "O01001.nc", BAD)
    url = "/api/programs/O01001.nc/versions/1/release"
    refused = app.client.post(url, headers=app.api(Role.APPROVER))
    assert refused.status_code == 409
    assert "line 4" in refused.json()["detail"]
    blank = app.client.post(url, json={"override": ""}, headers=app.api(Role.APPROVER))
    assert blank.status_code == 400
    done = app.client.post(
        url, json={"override": "G999 is this shop's macro"}, headers=app.api(Role.APPROVER)
    )
    assert done.status_code == 200
    assert done.json()["state"] == "released"
    row = _overrides(app, "O01001.nc")[-1]
    assert row.detail["to"] == "release"
    assert row.detail["reason"] == "G999 is this shop's macro"
    # a clean version is released without one
    _put(app, "O01000.nc", CLEAN)
    clean = app.client.post(
        "/api/programs/O01000.nc/versions/1/release", headers=app.api(Role.APPROVER)
    )
    assert clean.status_code == 200


def test_a_program_larger_than_the_check_reads_is_an_error(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(program_checks, "CHECK_BYTES", 100)
    result = program_checks.run("BIG.nc", CLEAN * 10, None)
    assert not result.ok  # not checked must never pass: it would release and send unchecked
    assert len(result.errors) == 1
    assert "not checked" in result.errors[0].message
    # under the bound the same text is run
    assert program_checks.run("BIG.nc", CLEAN, None).problems == ()


def test_the_limits_key_ignores_the_name_and_follows_the_envelope() -> None:
    a = MachineLimits(name="a", family="haas", travel={"X": (-30.0, 0.0)})
    b = MachineLimits(name="b", family="haas", travel={"X": (-30.0, 0.0)})
    c = MachineLimits(name="a", family="haas", travel={"X": (-31.0, 0.0)})
    assert program_checks.limits_key(a) == program_checks.limits_key(b)
    assert program_checks.limits_key(a) != program_checks.limits_key(c)
    assert program_checks.limits_key(None) == ""


def test_a_called_program_is_found_in_the_library(app: App, tmp_path: Path) -> None:
    sub = b"%\nO09010 (SUB)\nG00 X1.\nM99\n%\n"
    main = b"%\nO01003 (MAIN)\nG00 G90 G54 X0. Y0.\nM98 P9011\nM30\n%\n"
    first = _put(app, "O01003.nc", main)
    # O09011 is not in the library: a warning on the call's line
    assert _lines(first["check"], "warning") == [4]
    _put(app, "O09011.nc", sub.replace(b"O09010", b"O09011"))
    second = _put(app, "O01003.nc", main + b"(AGAIN)\n")
    assert second["check"]["warnings"] == 0, second["check"]


def test_a_shop_may_have_the_checks_errors_shown_only(tmp_path: Path) -> None:
    from opendnc.errors import InputError
    from opendnc.server.actions import policy
    from opendnc.server.config.shop import parse_config
    from opendnc.server.core.errors import Conflict
    from opendnc.server.library.checks import Checked

    def config(line: str) -> Any:
        return parse_config(f"[library]\npath = 'lib'\n{line}\n", base=tmp_path).library

    assert config("").check_blocks is True
    assert config("check = 'block'").check_blocks is True
    assert config("check = 'warn'").check_blocks is False
    with pytest.raises(InputError, match=r"library\.check"):
        config("check = 'off'")
    problem = {"line": 3, "block": None, "severity": "error", "message": "G999 is not a G"}
    failed = Checked(1, "", "haas", 1, 0, "", [problem], {}, None)
    wanted = r"^O1 v1: the program check found 1 error, on line 3: G999 is not a G; a programmer"
    with pytest.raises(Conflict, match=wanted):
        policy.check_passes(failed, None, "O1 v1")
    assert policy.check_passes(failed, "why", "O1 v1") is True  # overridden: audited
    assert policy.check_passes(failed, None, "O1 v1", blocks=False) is False  # shown only


def _kept(app: App, name: str) -> list[tuple[int, str, int]]:
    # (version, limits, errors) of the kept checks of the program ``name``
    from opendnc.server.store.models import Program, ProgramVersion

    with app.server.sessions() as s:
        rows = s.execute(
            select(ProgramVersion.number, VersionCheck.limits, VersionCheck.errors)
            .join(VersionCheck, VersionCheck.version_id == ProgramVersion.id)
            .join(Program, Program.id == ProgramVersion.program_id)
            .where(Program.name == name)
        )
        return [tuple(r) for r in rows]


def test_versions_from_the_inbox_and_the_folder_are_checked_when_saved(app: App) -> None:
    from opendnc.server.library import inbox
    from tests.server.harness import wait_for

    with app.server.sessions.begin() as s:
        received = inbox.store(
            s, "tnc", BAD, folder=app.server.config.library.inbox, name="O01010.nc"
        )
        received_id = received.id
    reply = app.client.post(f"/api/inbox/{received_id}/accept", headers=app.api(Role.PROGRAMMER))
    assert reply.status_code == 200, reply.text
    assert _kept(app, "O01010.nc") == [(1, "", 1)]  # before anyone asked for it

    (app.server.config.library.path / "O01011.nc").write_bytes(BAD)
    wait_for("the watcher's checked version", lambda: _kept(app, "O01011.nc") == [(1, "", 1)])
