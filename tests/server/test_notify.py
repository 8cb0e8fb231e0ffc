"""LISTEN/NOTIFY between servers on the real PostgreSQL: delivered at commit, never on a
rollback, and a listener whose connection was cut comes back and says so."""

from __future__ import annotations

import asyncio
from collections.abc import Iterator

import pytest
from sqlalchemy import Engine, text
from sqlalchemy.orm import Session, sessionmaker

from opendnc.server.store.db import make_engine, make_sessions
from opendnc.server.store.notify import Listener, Notice, Topic, notify
from tests.server.conftest import _pg_database


@pytest.fixture
def pg_url() -> Iterator[str]:
    yield from _pg_database()


async def _eventually(condition: object, timeout: float = 10.0) -> None:
    async with asyncio.timeout(timeout):
        while not condition():  # type: ignore[operator]
            await asyncio.sleep(0.02)


def test_a_notice_arrives_at_commit_and_never_after_a_rollback(pg_url: str) -> None:
    engine = make_engine(pg_url)
    sessions = make_sessions(engine)
    got: list[Notice] = []

    async def scenario() -> None:
        listener = Listener(pg_url, got.append)
        task = asyncio.create_task(listener.run())
        try:
            await asyncio.wait_for(listener.connected.wait(), 10)
            with sessions() as session:
                notify(session, Topic.JOB, "17")
                session.rollback()  # undone: never delivered
            with sessions.begin() as session:
                notify(session, Topic.CANCEL, "18")
                await asyncio.sleep(0.3)
                assert got == []  # not before the commit
            await _eventually(lambda: got)
            await asyncio.sleep(0.2)
            assert got == [Notice(Topic.CANCEL, "18")]
        finally:
            task.cancel()
            with pytest.raises(asyncio.CancelledError):
                await task

    try:
        asyncio.run(scenario())
    finally:
        engine.dispose()


def test_a_cut_listener_reconnects_and_says_so(pg_url: str) -> None:
    engine: Engine = make_engine(pg_url)
    sessions: sessionmaker[Session] = make_sessions(engine)
    got: list[Notice] = []
    reconnects: list[int] = []

    async def scenario() -> None:
        listener = Listener(pg_url, got.append, on_reconnect=lambda: reconnects.append(1))
        task = asyncio.create_task(listener.run())
        try:
            await asyncio.wait_for(listener.connected.wait(), 10)
            with sessions.begin() as session:  # cut the listener's connection
                session.execute(
                    text(
                        "SELECT pg_terminate_backend(pid) FROM pg_stat_activity "
                        "WHERE datname = current_database() AND query LIKE 'LISTEN%'"
                    )
                )
            await _eventually(lambda: listener.connections >= 2)
            with sessions.begin() as session:
                notify(session, Topic.LIBRARY, "O1000.nc")
            await _eventually(lambda: got)
            assert got == [Notice(Topic.LIBRARY, "O1000.nc")]
            assert len(reconnects) == 2
        finally:
            task.cancel()
            with pytest.raises(asyncio.CancelledError):
                await task

    try:
        asyncio.run(scenario())
    finally:
        engine.dispose()


def test_notify_does_nothing_on_sqlite(tmp_path: object) -> None:
    engine = make_engine(f"sqlite:///{tmp_path}/x.db")
    try:
        with make_sessions(engine).begin() as session:
            notify(session, Topic.JOB, "1")  # no error, no statement
    finally:
        engine.dispose()


def test_payloads_round_trip() -> None:
    assert Notice.decode(Notice(Topic.JOB, "a:b").encode()) == Notice(Topic.JOB, "a:b")
    assert Notice.decode("bare") == Notice(None, "bare")
    # a newer server's topic is read as none this server acts on, not an error
    assert Notice.decode("tomorrow:x") == Notice(None, "x")
    for topic in Topic:
        assert Notice.decode(Notice(topic, "k").encode()) == Notice(topic, "k")
