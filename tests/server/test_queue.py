"""The library's versions and states, the job queue's rules, users and keys."""

from __future__ import annotations

import hashlib
from concurrent.futures import ThreadPoolExecutor
from datetime import timedelta

import pytest
from sqlalchemy import select
from sqlalchemy.orm import Session, sessionmaker

from opendnc.errors import InputError
from opendnc.server import actions
from opendnc.server.access import auth
from opendnc.server.access.auth import Principal
from opendnc.server.actions.models import JobRequest
from opendnc.server.core.errors import Conflict, NotFound, Unauthorized
from opendnc.server.jobs import queue as jobs
from opendnc.server.kinds.haas_ngc import HaasNgcMachine
from opendnc.server.kinds.lsv2 import Lsv2Machine
from opendnc.server.library import versions as library
from opendnc.server.store import audit
from opendnc.server.store.models import ApiKey, JobKind, JobState, ProgramState, Role
from tests.server.actions_support import services

PROGRAM = b"%\nO01234 (BRACKET)\nG00 G90 X0. Y0.\nM30\n%\n"


MACHINES = [
    Lsv2Machine(name="mill-1", host="127.0.0.1"),
    HaasNgcMachine(name="vf2", host="127.0.0.1", released_only=True),
]


def _machines(session: Session) -> None:
    jobs.sync_machines(session, MACHINES)


def test_versions_are_content_addressed_and_released_one_at_a_time(
    sessions: sessionmaker[Session],
) -> None:
    with sessions.begin() as s:
        v1, created = library.add_version(s, "O01234", PROGRAM, author="ann", comment="first")
        assert created
        assert v1.number == 1
        assert v1.state is ProgramState.DRAFT
        assert v1.sha256 == hashlib.sha256(PROGRAM).hexdigest()
        same, created = library.add_version(s, "O01234", PROGRAM, author="ann")
        assert not created
        assert same.id == v1.id
        _v2, _ = library.add_version(s, "O01234", PROGRAM.replace(b"X0.", b"X5."), author="bob")
        library.release(s, "O01234", 1, actor="carl")
        library.release(s, "O01234", 2, actor="carl")
    with sessions() as s:
        versions = library.get_program(s, "O01234").versions
        # times come back in UTC on every backend (SQLite keeps no zone of its own)
        assert all(v.created.utcoffset() == timedelta(0) for v in versions)
        states = [v.state for v in versions]
        assert states == [ProgramState.SUPERSEDED, ProgramState.RELEASED]
        assert library.content(s, library.get_version(s, "O01234", 2)) == PROGRAM.replace(
            b"X0.", b"X5."
        )
        diff = library.diff(s, "O01234", 1, 2)
        assert "-G00 G90 X0. Y0." in diff
        assert "+G00 G90 X5. Y0." in diff
        with pytest.raises(Conflict, match="superseded"):
            library.release(s, "O01234", 1, actor="carl")
        actions = [r.action for r in audit.query(s, program="O01234")]
        assert actions.count("program.version") == 2
        assert actions.count("program.release") == 2


@pytest.mark.parametrize(
    "name", ["../etc/passwd", "a/b", "..", ".hidden", "", "x" * 101, "CON", "nul.nc", "O1\n"]
)
def test_bad_program_names_are_refused(sessions: sessionmaker[Session], name: str) -> None:
    with sessions() as s, pytest.raises(InputError):
        library.add_version(s, name, PROGRAM, author="ann")


def test_locked_program_takes_no_new_version(sessions: sessionmaker[Session]) -> None:
    with sessions.begin() as s:
        library.add_version(s, "O01234", PROGRAM, author="ann")
        library.set_locked(s, "O01234", True, actor="boss")
    with sessions() as s, pytest.raises(Conflict, match="locked"):
        library.add_version(s, "O01234", PROGRAM + b"\n", author="ann")


def test_released_only_machine_refuses_a_draft(sessions: sessionmaker[Session]) -> None:
    # The policy is the actions layer's (the one path of the API and the pages).
    svc = services(sessions, MACHINES)
    op = Principal("op", Role.OPERATOR)
    with sessions.begin() as s:
        _machines(s)
        library.add_version(s, "O01234", PROGRAM, author="ann")
    order = JobRequest(program="O01234", version=1, machines=["mill-1", "vf2"])
    with pytest.raises(Conflict, match="released programs only"):
        actions.queue.create_jobs(svc, op, order)
    with sessions() as s:
        assert jobs.list_jobs(s) == []  # nothing queued for mill-1 either
    with pytest.raises(Conflict, match="no released version"):
        actions.queue.create_jobs(svc, op, JobRequest(program="O01234", machines=["mill-1"]))


def test_a_send_to_many_goes_to_the_machines_that_take_it_and_names_each_refused(
    sessions: sessionmaker[Session],
) -> None:
    """ "All machines" with one refusing it refused the whole send, named one machine, and
    left no trace in the audit trail."""
    shop = [*MACHINES, HaasNgcMachine(name="vf4", host="127.0.0.1")]
    svc = services(sessions, shop)
    op = Principal("op", Role.OPERATOR)
    with sessions.begin() as s:
        jobs.sync_machines(s, shop)
        library.add_version(s, "O01234", PROGRAM, author="ann")  # a Haas program, a draft
    order = JobRequest(program="O01234", version=1, machines=["mill-1", "vf2", "vf4"])
    done = actions.queue.queue_each(svc, op, order)
    assert [j.machine for j in done.jobs] == ["vf4"]
    assert [r.machine for r in done.refused] == ["vf2", "mill-1"]  # the machine's own rule first
    vf2, mill = (r.reason for r in done.refused)
    assert "accepts released programs only" in vf2
    assert "the program check found 1 error" in mill
    refusal = done.refused[0]
    # on every machine: 409 naming each, and the refusals are in the audit trail all the same
    with pytest.raises(actions.queue.RefusedEverywhere) as nowhere:
        actions.queue.queue_each(svc, op, JobRequest(program="O01234", version=1, machines=["vf2"]))
    assert [r.machine for r in nowhere.value.refused] == ["vf2"]
    assert str(nowhere.value) == refusal.reason  # one machine: its own words, as before
    with sessions() as s:
        rows = audit.query(s, action="job.refused")
        assert [(r.machine, r.actor, r.result, r.program) for r in rows] == [
            ("vf2", "op", "refused", "O01234"),  # newest first
            ("mill-1", "op", "refused", "O01234"),
            ("vf2", "op", "refused", "O01234"),
        ]
        assert "released programs only" in rows[0].detail["error"]
        assert [j.machine for j in jobs.list_jobs(s)] == ["vf4"]


def test_queue_order_claim_retry_and_cancel(sessions: sessionmaker[Session]) -> None:
    with sessions.begin() as s:
        _machines(s)
        library.add_version(s, "O01234", PROGRAM, author="ann")
        library.release(s, "O01234", 1, actor="carl")
        version = library.get_version(s, "O01234", 1)
        a, b, c = (
            jobs.enqueue(s, JobKind.SEND, "mill-1", actor="op", version=version) for _ in range(3)
        )
        jobs.move(s, c.id, 0, actor="op")  # c goes first
    with sessions.begin() as s:
        first = jobs.claim(s, "mill-1", "srv")
        assert first is not None
        assert first.id == c.id
        assert jobs.claim(s, "mill-1", "srv") is None  # one job at a time per port
        jobs.fail(s, c.id, "link down", backoff=3600)  # queued again, not due for an hour
    with sessions.begin() as s:
        assert jobs.get_job(s, c.id).state is JobState.QUEUED
        second = jobs.claim(s, "mill-1", "srv")
        assert second is not None
        assert second.id == a.id
        jobs.finish(s, a.id, nbytes=len(PROGRAM))
        jobs.cancel(s, b.id, actor="op")
        assert jobs.claim(s, "mill-1", "srv") is None  # c is backing off, b cancelled
        with pytest.raises(Conflict):
            jobs.cancel(s, a.id, actor="op")
    with sessions() as s:
        sends = [r for r in audit.query(s, machine="mill-1") if r.action == "job.send"]
        assert [(r.job_id, r.result, r.bytes) for r in sends] == [
            (a.id, "ok", len(PROGRAM)),
            (c.id, "retry", None),
        ]


def test_dripfeed_is_never_retried_and_restarts_from_a_line(
    sessions: sessionmaker[Session],
) -> None:
    with sessions.begin() as s:
        _machines(s)
        version, _ = library.add_version(s, "O01234", PROGRAM, author="ann")
        job = jobs.enqueue(s, JobKind.DRIPFEED, "mill-1", actor="op", version=version)
        assert jobs.claim(s, "mill-1", "srv") is not None
        jobs.fail(s, job.id, "XOFF for 60 s", line=3, nbytes=27)
    with sessions.begin() as s:
        broken = jobs.get_job(s, job.id)
        assert broken.state is JobState.INTERRUPTED
        # what the feed had done, for the history and the restart
        assert (broken.line, broken.bytes_done) == (3, 27)
        (row,) = [r for r in audit.query(s, machine="mill-1") if r.action == "job.dripfeed"]
        assert (row.result, row.bytes) == ("interrupted", 27)
        again = jobs.retry(s, job.id, actor="op", from_line=120)
        assert again.params == {"from_line": 120, "retry_of": job.id}
        assert again.kind is JobKind.DRIPFEED
        assert again.state is JobState.QUEUED


def test_restart_marks_running_jobs_interrupted(sessions: sessionmaker[Session]) -> None:
    with sessions.begin() as s:
        _machines(s)
        version, _ = library.add_version(s, "O01234", PROGRAM, author="ann")
        library.release(s, "O01234", 1, actor="carl")
        running = jobs.enqueue(s, JobKind.SEND, "mill-1", actor="op", version=version)
        waiting = jobs.enqueue(s, JobKind.SEND, "mill-1", actor="op", version=version)
        jobs.claim(s, "mill-1", "srv")
    with sessions.begin() as s:
        assert [j.id for j in jobs.recover(s, "srv")] == [running.id]
    with sessions() as s:
        assert jobs.get_job(s, running.id).state is JobState.INTERRUPTED
        assert "server stopped" in jobs.get_job(s, running.id).error
        assert jobs.get_job(s, waiting.id).state is JobState.QUEUED


def test_concurrent_claims_never_take_one_machine_twice(
    sessions: sessionmaker[Session], db_url: str
) -> None:
    # Several workers (servers sharing the database) race for the same machine's queue.
    with sessions.begin() as s:
        _machines(s)
        version, _ = library.add_version(s, "O01234", PROGRAM, author="ann")
        for _ in range(6):
            jobs.enqueue(s, JobKind.SEND, "mill-1", actor="op", version=version)

    def worker(n: int) -> int | None:
        with sessions.begin() as s:
            job = jobs.claim(s, "mill-1", f"srv{n}")
            return job.id if job else None

    with ThreadPoolExecutor(4) as pool:
        claimed = [j for j in pool.map(worker, range(8)) if j is not None]
    assert len(claimed) == 1


def test_keys_and_passwords(sessions: sessionmaker[Session]) -> None:
    with sessions.begin() as s:
        auth.create_user(s, "ann", Role.PROGRAMMER, password="correct horse")
        _, key = auth.create_key(s, "ann", Role.OPERATOR, label="tablet")
        with pytest.raises(InputError, match="more rights"):
            auth.create_key(s, "ann", Role.ADMIN)
    with sessions.begin() as s:
        who = auth.authenticate_key(s, key)
        assert (who.name, who.role) == ("ann", Role.OPERATOR)
        assert auth.check_password(s, "ann", "correct horse").role is Role.PROGRAMMER
        with pytest.raises(Unauthorized):
            auth.check_password(s, "ann", "wrong")
        auth.revoke_key(s, who.key_id or 0, actor="admin")
    with sessions() as s:
        with pytest.raises(Unauthorized):
            auth.authenticate_key(s, key)
        stored = [k.key_hash for k in s.scalars(select(ApiKey))]
        assert key not in stored
        assert hashlib.sha256(key.encode()).hexdigest() in stored
        # a password check writes nothing: the login that makes it audits it
        # (tests/web/test_sessions.py), refused or not
        assert audit.query(s, action="login") == []
        with pytest.raises(NotFound):
            auth.create_key(s, "nobody", Role.VIEWER)
