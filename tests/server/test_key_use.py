"""The keys' last use: noted by requests, written by the component once a period and at its
stop, in one statement for every key, never moving a time backwards (SQLite and PostgreSQL)."""

from __future__ import annotations

import asyncio
from datetime import timedelta
from pathlib import Path

import pytest
from sqlalchemy import create_engine
from sqlalchemy.exc import OperationalError
from sqlalchemy.orm import Session, sessionmaker

from opendnc.server.access import auth
from opendnc.server.access.key_use import KeyUse
from opendnc.server.core.errors import Unauthorized
from opendnc.server.store.db import read_only
from opendnc.server.store.models import ApiKey, Role, utcnow


def _keys(sessions: sessionmaker[Session], count: int) -> list[int]:
    with sessions.begin() as session:
        return [
            auth.create_key(session, "svc", Role.VIEWER, create_user_role=Role.VIEWER)[0].id
            for _ in range(count)
        ]


def _last_used(sessions: sessionmaker[Session], key_id: int) -> object:
    with sessions() as session:
        row = session.get(ApiKey, key_id)
        assert row is not None
        return row.last_used


def test_the_component_writes_what_was_noted_each_period_and_at_its_stop(
    sessions: sessionmaker[Session],
) -> None:
    first, second = _keys(sessions, 2)
    uses = KeyUse(sessions, every=0.1)

    async def scenario() -> None:
        await uses.start()
        uses.note(first)
        deadline = asyncio.get_running_loop().time() + 30
        while _last_used(sessions, first) is None:
            assert asyncio.get_running_loop().time() < deadline, "never written"
            await asyncio.sleep(0.05)
        uses.every = 3600.0  # the next period is far away: only the stop writes now
        await asyncio.sleep(0.3)  # the loop is asleep in its (old) period or the new one
        uses.note(second)
        await uses.stop()

    asyncio.run(scenario())
    assert _last_used(sessions, first) is not None
    assert _last_used(sessions, second) is not None
    assert uses.pending() == {}


def test_a_write_that_fails_keeps_the_uses_for_the_next_one(
    sessions: sessionmaker[Session], tmp_path: Path
) -> None:
    (key_id,) = _keys(sessions, 1)
    moment = utcnow() - timedelta(seconds=5)
    # A database that cannot be opened (a file in a folder that does not exist).
    away = create_engine(f"sqlite:///{tmp_path / 'missing' / 'x.db'}")
    uses = KeyUse(sessionmaker(away))
    uses.note(key_id, moment)
    uses.note(key_id, moment - timedelta(seconds=30))  # an older note does not replace it
    with pytest.raises(OperationalError):
        uses.flush()
    assert uses.pending() == {key_id: moment}
    uses.sessions = sessions  # the database is back
    assert uses.flush() == 1
    assert _last_used(sessions, key_id) == moment
    assert uses.pending() == {}


def test_a_checked_key_is_kept_for_seconds_and_a_revoked_or_unknown_one_never(
    sessions: sessionmaker[Session],
) -> None:
    with sessions.begin() as session:
        _row, key = auth.create_key(session, "svc", Role.VIEWER, create_user_role=Role.VIEWER)
        _row2, other = auth.create_key(session, "svc", Role.VIEWER)
    now = [0.0]
    cache = auth.KeyCache(seconds=5.0, clock=lambda: now[0])
    uses = KeyUse(sessions)
    reads = read_only(sessions)
    first = auth.authenticate(reads, key, uses, cache)
    assert cache.get(key) == first
    assert cache.get(key, web=True) is None  # a cookie is checked on its own
    # Revoked in the database (another server): still taken until the seconds are up.
    with sessions.begin() as session:
        auth.revoke_key(session, first.who.key_id or 0, actor="admin")
    now[0] = 4.9
    assert auth.authenticate(reads, key, uses, cache).who == first.who
    now[0] = 5.1
    with pytest.raises(Unauthorized):
        auth.authenticate(reads, key, uses, cache)
    assert cache.get(key) is None  # a refused key is not kept
    # Forgotten at once when this server revokes it.
    auth.authenticate(reads, other, uses, cache)
    second = cache.get(other)
    assert second is not None
    cache.forget(second.who.key_id)
    assert cache.get(other) is None
    with pytest.raises(Unauthorized):
        auth.authenticate(reads, "odk_" + "x" * 43, uses, cache)
    assert uses.pending().keys() == {first.who.key_id, second.who.key_id}
