"""A running job is ended once, however many writers try at the same moment.

Seen under load in a three-server cluster: one load job with two "done" rows. A server whose
lease renewal came late was fenced while its "done" was on its way to the database, took its
machine back and claimed the job again; the late write and the new run's both read the job
running (PostgreSQL's read committed: a plain read does not wait for another transaction's
uncommitted write) and both ended it. The ending now reads the job's row locked: the second
writer waits for the first and then finds the job ended.
"""

from __future__ import annotations

import threading
import time

from sqlalchemy import select, text
from sqlalchemy.orm import Session, sessionmaker

from opendnc.server.core.errors import Conflict
from opendnc.server.jobs import queue as jobs
from opendnc.server.library import versions as library
from opendnc.server.store.models import AuditEntry, JobKind, JobState
from tests.server.conftest import on
from tests.server.test_queue import PROGRAM, _machines


def _waiting_for_a_lock(sessions: sessionmaker[Session]) -> bool:
    with sessions() as s:
        waiting = s.execute(
            text(
                "SELECT count(*) FROM pg_stat_activity"
                " WHERE datname = current_database() AND wait_event_type = 'Lock'"
            )
        ).scalar_one()
    return int(waiting) > 0


@on("postgresql")
def test_two_writers_ending_one_job_at_once_end_it_once(sessions: sessionmaker[Session]) -> None:
    with sessions.begin() as s:
        _machines(s)
        library.add_version(s, "O01234", PROGRAM, author="ann")
        library.release(s, "O01234", 1, actor="carl")
        version = library.get_version(s, "O01234", 1)
        job_id = jobs.enqueue(s, JobKind.SEND, "mill-1", actor="op", version=version).id
    with sessions.begin() as s:
        claimed = jobs.claim(s, "mill-1", "srv")
        assert claimed is not None
        assert claimed.id == job_id

    second: list[object] = []

    def end_it_too() -> None:
        try:
            with sessions.begin() as s2:
                second.append(jobs.finish(s2, job_id, nbytes=len(PROGRAM)).state)
        except Conflict as exc:
            second.append(exc)

    with sessions.begin() as s1:
        jobs.finish(s1, job_id, nbytes=len(PROGRAM))
        s1.flush()  # written, not committed: the row is this transaction's
        other = threading.Thread(target=end_it_too)
        other.start()
        end = time.monotonic() + 30
        while not _waiting_for_a_lock(sessions):  # the second writer waits on the row
            assert other.is_alive(), second
            assert time.monotonic() < end, "the second writer never waited for the row"
            time.sleep(0.02)
    other.join(30)
    assert not other.is_alive()
    assert len(second) == 1, second
    assert isinstance(second[0], Conflict), second
    with sessions() as s:
        assert jobs.get_job(s, job_id).state is JobState.DONE
        ended = s.scalars(
            select(AuditEntry).where(AuditEntry.action == "job.send", AuditEntry.result == "ok")
        ).all()
    assert [e.job_id for e in ended] == [job_id]


@on("postgresql")
def test_a_locked_read_sees_the_job_afresh(sessions: sessionmaker[Session]) -> None:
    # a lock asked for on a job this session has read before reads it again (SQLite's
    # sessions begin with the database's write lock: no other writer meanwhile there)
    with sessions.begin() as s:
        _machines(s)
        library.add_version(s, "O01234", PROGRAM, author="ann")
        library.release(s, "O01234", 1, actor="carl")
        version = library.get_version(s, "O01234", 1)
        job_id = jobs.enqueue(s, JobKind.SEND, "mill-1", actor="op", version=version).id
    with sessions() as s:
        held = jobs.get_job(s, job_id)
        assert held.state is JobState.QUEUED
        with sessions.begin() as other:
            assert jobs.claim(other, "mill-1", "srv") is not None
        assert jobs.get_job(s, job_id, lock=True).state is JobState.RUNNING
        s.rollback()
