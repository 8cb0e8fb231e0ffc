"""One policy decision: queue, retry, a control's remote request, the file browser's put, a
release and the net share all ask :func:`opendnc.server.actions.policy.authorize`, once per
machine, and the server acts on nothing else.

The whole server runs in this process around memory controls (tests/server/inprocess_app.py);
the net share copies between real local folders. The expected answers are the rules as
written in docs/server.md, not the code's output: a draft never reaches a ``released_only``
machine, whichever path it takes, and it reaches one that takes drafts.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from datetime import timedelta
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import select

from opendnc.server.access.auth import Principal
from opendnc.server.actions import Services, policy
from opendnc.server.core.errors import Conflict
from opendnc.server.jobs import queue as jobs
from opendnc.server.kinds.connector import Reception
from opendnc.server.library import versions as library
from opendnc.server.netshare.share import NetShare
from opendnc.server.store.models import (
    AuditEntry,
    Job,
    JobKind,
    JobState,
    ProgramState,
    Role,
    utcnow,
)
from tests.server.harness import wait_for
from tests.server.inprocess_app import App, MemoryControl, running

TNC = "P.H"
TNC_TEXT = b"0 BEGIN PGM P MM\n1 L X+0 R0 FMAX\n2 END PGM P MM\n"
HAAS = "O01000.nc"
HAAS_TEXT = b"%\nO01000\nG00 G90 G54 X0. Y0.\nM30\n%\n"
DRAFT_ONLY = "O02000.nc"  # a program with no released version
# the program check's error: a block no control runs
BROKEN = b"%\nO01001\nG00 G90 G54 X0. Y0.\nG999\nM30\n%\n"
REASON = "proved out on the machine by hand"


@pytest.fixture(scope="module")
def app(tmp_path_factory: pytest.TempPathFactory) -> Iterator[App]:
    tmp = tmp_path_factory.mktemp("decision")
    for folder in ("nas", "share-ngc", "share-ngc-ro"):
        (tmp / folder).mkdir()
    lsv2 = {"kind": "lsv2", "host": "127.0.0.1", "port": 1, "poll_interval": 0.1}
    serial = {"kind": "haas_serial", "serial": "socket://127.0.0.1:1", "poll_interval": 0.1}
    ngc = {"kind": "haas_ngc", "host": "127.0.0.1", "poll_interval": 0.1}
    machines: list[dict[str, object]] = [
        {"name": "tnc", **lsv2},
        {"name": "tnc-ro", **lsv2, "released_only": True},
        {"name": "haas", **serial, "dripfeed": True},
        {"name": "haas-ro", **serial, "released_only": True},
        {"name": "ngc", **ngc, "share": str(tmp / "share-ngc")},
        {"name": "ngc-ro", **ngc, "share": str(tmp / "share-ngc-ro"), "released_only": True},
    ]
    extra = (
        f'[netshare]\npath = "{tmp / "nas"}"\nmachines = ["ngc", "ngc-ro"]\n'
        f'archive = "{tmp / "archive"}"\ninterval = 3600\n'  # scanned by the tests only
        "[requests]\ndelay = 0.1\n"
    )
    with running(tmp, machines, extra=extra) as served:
        with served.server.sessions.begin() as s:
            moves = ((TNC, TNC_TEXT, b"X+0", b"X+1"), (HAAS, HAAS_TEXT, b"X0.", b"X1."))
            for name, text, here, there in moves:
                library.add_version(s, name, text, author="t")
                library.release(s, name, 1, actor="t")
                # v2, a draft one millimetre over
                library.add_version(s, name, text.replace(here, there), author="t")
            library.add_version(s, DRAFT_ONLY, HAAS_TEXT.replace(b"1000", b"2000"), author="t")
        yield served


@dataclass
class Spy:
    """Every call of ``policy.authorize``: the path and the machines it decided for."""

    calls: list[tuple[policy.Via, tuple[str, ...]]] = field(default_factory=list)

    def take(self) -> list[tuple[policy.Via, tuple[str, ...]]]:
        taken, self.calls = self.calls, []
        return taken


@pytest.fixture
def spy(monkeypatch: pytest.MonkeyPatch) -> Spy:
    seen = Spy()
    real = policy.authorize

    def counted(
        svc: Services,
        actor: policy.Actor,
        version: policy.Wanted | None,
        machines: Any,
        action: policy.Action,
        **kw: Any,
    ) -> policy.Decision:
        seen.calls.append((action.via, tuple(machines)))
        return real(svc, actor, version, machines, action, **kw)

    monkeypatch.setattr(policy, "authorize", counted)
    return seen


def _services(app: App) -> Services:
    return app.server.core.get(Services)


def _failed_job(app: App, machine: str, program: str, number: int) -> int:
    with app.server.sessions.begin() as s:
        version = library.get_version(s, program, number)
        job = jobs.enqueue(
            s,
            JobKind.SEND,
            machine,
            actor="t",
            version=version,
            not_before=utcnow() + timedelta(days=1),  # never runs by itself here
        )
        job.state = JobState.FAILED
        return job.id


def _audit(app: App, action: str, machine: str | None = None) -> list[AuditEntry]:
    with app.server.sessions() as s:
        stmt = select(AuditEntry).where(AuditEntry.action == action).order_by(AuditEntry.id)
        if machine is not None:
            stmt = stmt.where(AuditEntry.machine == machine)
        return list(s.scalars(stmt))


def _request(app: App, machine: str, text: str) -> AuditEntry:
    """Punch ``text`` at ``machine``'s control; its ``program.request`` audit row."""
    before = len(_audit(app, "program.request", machine))
    control: MemoryControl = app.controls[machine]
    punched = [Reception(text.encode())]

    async def listen(seconds: float) -> Reception | None:
        if punched:
            return punched.pop()
        await asyncio.sleep(seconds)
        return None

    control.listen = listen  # type: ignore[method-assign]
    control.listens = True
    try:
        wait_for(
            f"{machine}'s request answered",
            lambda: len(_audit(app, "program.request", machine)) > before,
            timeout=15,
        )
    finally:
        control.listens = False
    return _audit(app, "program.request", machine)[-1]


def _scan_until(app: App, done: Any, what: str) -> Any:
    net = app.server.core.get(NetShare)
    deadline = time.monotonic() + 15
    pushed: list[tuple[str, str]] = []
    refused: list[tuple[str, str, str]] = []
    while time.monotonic() < deadline:
        report = net.scan_sync()
        pushed += report.pushed
        refused += report.refused
        if done(pushed, refused):
            return pushed, refused
        time.sleep(0.05)
    raise AssertionError(f"{what} did not happen: pushed {pushed}, refused {refused}")


def _each_machine_once(calls: list[tuple[policy.Via, tuple[str, ...]]], via: policy.Via) -> None:
    machines = [m for v, ms in calls for m in ms]
    assert {v for v, _ in calls} == {via}, calls
    assert len(machines) == len(set(machines)), f"a machine decided twice: {calls}"


def test_a_draft_reaches_no_released_only_machine_by_any_path_and_each_asks_once(
    app: App, spy: Spy
) -> None:
    admin = app.api(Role.ADMIN)

    # queue: the draft v2, to both machines at once, goes to the one that takes drafts
    sent = app.client.post(
        "/api/jobs",
        json={"program": TNC, "version": 2, "machines": ["tnc", "tnc-ro"]},
        headers=admin,
    )
    assert sent.status_code == 201, sent.text
    assert [j["machine"] for j in sent.json()] == ["tnc"]
    assert "tnc-ro" in sent.headers["OpenDNC-Refused"]
    assert "released programs only" in sent.headers["OpenDNC-Refused"]
    assert spy.take() == [(policy.Via.QUEUE, ("tnc", "tnc-ro"))]

    # retry: a failed send of the draft is refused where the draft is refused
    for machine, status in (("tnc-ro", 409), ("tnc", 201)):
        job = _failed_job(app, machine, TNC, 2)
        retried = app.client.post(f"/api/jobs/{job}/retry", headers=admin)
        assert retried.status_code == status, retried.text
        assert spy.take() == [(policy.Via.RETRY, (machine,))]
        if status == 409:
            assert "version 2 is draft" in retried.text

    # file put: the upload is a draft first, which tnc-ro refuses (and stores nothing)
    for machine, refused in (("tnc-ro", True), ("tnc", False)):
        put = app.client.post(
            f"/machines/{machine}/files/upload",
            data={"folder": "TNC:/nc_prog"},
            files={"file": (f"UP-{machine}.H", b"1 L X+9\n")},
            headers=app.page(Role.ADMIN),
            follow_redirects=False,
        )
        assert (put.status_code == 409) is refused, put.text
        assert spy.take() == [(policy.Via.PUT_FILE, (machine,))]
    with app.server.sessions() as s:
        assert [p.name for p in library.list_programs(s, "UP-")] == ["UP-tnc.H"]

    # remote request: the released version (what a send without a number means), never
    # the newer draft; a program with no released version is not sent, whatever the machine
    for machine in ("haas-ro", "haas"):
        row = _request(app, machine, "%\nO09999 (REQ O1000 REQ O2000)\nM30\n%\n")
        assert row.detail["sent"] == [HAAS], row.detail
        assert row.detail["refused"] == [f"{DRAFT_ONLY} NOT RELEASED"], row.detail
        calls = spy.take()
        assert calls == [(policy.Via.REQUEST, (machine,))] * 2, calls
        with app.server.sessions() as s:
            chosen = jobs.version_to_send(s, HAAS, None)
            job = s.scalars(
                select(Job)
                .where(Job.machine == machine, Job.kind == JobKind.SEND)
                .order_by(Job.id.desc())
            ).first()
            assert job is not None
            assert job.version_id == chosen.id
            assert chosen.number == 1
            with pytest.raises(jobs.NotReleased):
                jobs.version_to_send(s, DRAFT_ONLY, None)

    # net share: the draft's bytes on the NAS go to ngc, not to ngc-ro
    root = Path(app.server.config.netshare.path)  # type: ignore[union-attr]
    with app.server.sessions() as s:
        draft = library.content(s, library.get_version(s, HAAS, 2))
    (root / HAAS).write_bytes(draft)
    pushed, refused = _scan_until(
        app, lambda p, r: bool(p) and bool(r), "the draft's push and refusal"
    )
    assert pushed == [("ngc", HAAS)]
    assert [(m, n) for m, n, _ in refused] == [("ngc-ro", HAAS)]
    assert "version 2 is draft" in refused[0][2]
    # the file is stable (two scans alike) in the scan that pushes it: one decision each
    share_calls = spy.take()
    _each_machine_once(share_calls, policy.Via.SHARE)
    assert sorted(share_calls) == [(policy.Via.SHARE, ("ngc",)), (policy.Via.SHARE, ("ngc-ro",))]

    # release: a version whose check fails is refused, a clean one released
    with app.server.sessions.begin() as s:
        library.add_version(s, "O01001.nc", BROKEN, author="t")
        library.add_version(s, "O01002.nc", HAAS_TEXT.replace(b"1000", b"1002"), author="t")
    broken = app.client.post("/api/programs/O01001.nc/versions/1/release", headers=admin)
    assert broken.status_code == 409, broken.text
    assert "program check found" in broken.text
    clean = app.client.post("/api/programs/O01002.nc/versions/1/release", headers=admin)
    assert clean.status_code == 200, clean.text
    assert spy.take() == [(policy.Via.RELEASE, ()), (policy.Via.RELEASE, ())]


def test_a_decision_goes_stale_when_the_version_changes_before_it_is_confirmed(
    app: App,
) -> None:
    svc = _services(app)
    who = Principal("ann", Role.ADMIN)
    with app.server.sessions.begin() as s:
        library.add_version(s, "O03000.nc", HAAS_TEXT.replace(b"1000", b"3000"), author="t")
        library.release(s, "O03000.nc", 1, actor="t")
        library.add_version(s, "O03000.nc", HAAS_TEXT.replace(b"1000", b"3001"), author="t")

    # named: v1, released when prepared, superseded before the confirm
    named = policy.authorize(
        svc, who, policy.Wanted("O03000.nc", 1), ["haas-ro"], policy.Action.queue(JobKind.SEND)
    )
    assert named.verdict("haas-ro").allowed
    assert named.state is ProgramState.RELEASED
    # "the released one": v1 when prepared, v2 at the confirm
    released = policy.authorize(
        svc, who, policy.Wanted("O03000.nc"), ["haas"], policy.Action.queue(JobKind.SEND)
    )
    assert released.verdict("haas").allowed
    with app.server.sessions.begin() as s:
        library.release(s, "O03000.nc", 2, actor="t")  # v1 is superseded

    confirmed = svc.write(named.confirm)
    verdict = confirmed.verdict("haas-ro")
    assert verdict.refusal is policy.Refusal.RELEASED_ONLY
    assert "version 1 is superseded" in verdict.reason
    with pytest.raises(policy.Stale, match="version 1 was decided on"):
        svc.write(released.confirm)
    with pytest.raises(Conflict, match="superseded"):
        svc.write(lambda s: named.confirm(s).require_all())  # prepared, never confirmed


def test_an_override_carries_who_and_why_into_the_audit(app: App) -> None:
    # a program of the other family: its check on a TNC is an error, overridden here
    body = {"program": HAAS, "machines": ["tnc"], "override": REASON}
    refused = app.client.post(
        "/api/jobs", json={**body, "override": None}, headers=app.api(Role.PROGRAMMER)
    )
    assert refused.status_code == 409, refused.text
    sent = app.client.post("/api/jobs", json=body, headers=app.api(Role.PROGRAMMER))
    assert sent.status_code == 201, sent.text
    job = sent.json()[0]
    assert job["params"]["check_override"] == REASON
    rows = [r for r in _audit(app, "program.check_override") if r.job_id == job["id"]]
    assert len(rows) == 1
    row = rows[0]
    assert (row.actor, row.machine, row.program) == ("programmer", "tnc", HAAS)
    assert (row.detail["reason"], row.detail["by"], row.detail["to"]) == (
        REASON,
        "programmer",
        "send",
    )
    assert row.detail["errors"] >= 1

    # a retry keeps the override, and says whose it was
    def ended() -> bool:
        with app.server.sessions() as s:
            return jobs.get_job(s, job["id"]).state is JobState.DONE

    wait_for("the overridden send done", ended, timeout=15)
    with app.server.sessions.begin() as s:
        jobs.get_job(s, job["id"]).state = JobState.FAILED  # as if the load had failed
    retried = app.client.post(f"/api/jobs/{job['id']}/retry", headers=app.api(Role.OPERATOR))
    assert retried.status_code == 201, retried.text
    again = _audit(app, "program.check_override")[-1]
    assert again.job_id == retried.json()["id"]
    assert (again.actor, again.detail["by"], again.detail["reason"]) == (
        "operator",
        "programmer",
        REASON,
    )
