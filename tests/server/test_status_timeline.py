"""The status timeline in the database: changes only, written off the event loop, read back
by a new timeline (as after a server restart), pruned after the retention; and migration 0004
up from 0003 and back. On SQLite and PostgreSQL."""

from __future__ import annotations

import asyncio
import time
from datetime import UTC, datetime, timedelta
from pathlib import Path

import pytest
from sqlalchemy import Engine, func, inspect, select, text
from sqlalchemy.orm import Session, sessionmaker

from opendnc.server.config.shop import ConfigError, parse_config
from opendnc.server.core.events import EventBus, JobQueued, MachineStatusChanged
from opendnc.server.core.jobwords import JobKind
from opendnc.server.core.status import MachineStatus
from opendnc.server.machines.timeline import Timeline, running
from opendnc.server.store.db import current_revision, make_engine, migrate
from opendnc.server.store.models import StatusSample

T0 = datetime(2026, 1, 5, 8, 0, tzinfo=UTC)


def _status(execution: str, mode: str = "AUTOMATIC") -> MachineStatus:
    return MachineStatus(at=T0, available=True, execution=execution, mode=mode)


def note(
    tl: Timeline,
    name: str,
    at: datetime,
    execution: str,
    mode: str = "AUTOMATIC",
    online: bool = True,
) -> bool:
    """Note a reachable control's execution and mode at ``at`` (what a status poll reads)."""
    return tl.note(name, _status(execution, mode), online=online, at=at)


def _event(execution: str) -> MachineStatusChanged:
    return MachineStatusChanged("m", True, _status(execution))


def _rows(sessions: sessionmaker[Session]) -> list[tuple[str, datetime, str, str, str]]:
    with sessions() as session:
        rows = session.scalars(select(StatusSample).order_by(StatusSample.id)).all()
        return [(r.machine, r.at, r.state, r.mode, r.execution) for r in rows]


def test_migration_0004_up_from_0003_and_back(db_url: str) -> None:
    engine = make_engine(db_url)
    try:
        migrate(engine, "0003")
        with engine.begin() as conn:
            conn.execute(
                text(
                    "INSERT INTO dprnt_lines (machine, at, text, fields, complete) "
                    "VALUES ('vf2', CURRENT_TIMESTAMP, 'X 1.5', '[]', TRUE)"
                )
            )
        migrate(engine, "0004")
        assert current_revision(engine) == "0004"
        columns = {c["name"] for c in inspect(engine).get_columns("status_samples")}
        assert columns == {"id", "machine", "at", "state", "mode", "execution"}
        indexes = sorted(i["column_names"] for i in inspect(engine).get_indexes("status_samples"))
        assert indexes == [["at"], ["machine", "at"]]
        migrate(engine, "0003")
        assert current_revision(engine) == "0003"
        assert "status_samples" not in inspect(engine).get_table_names()
        with engine.connect() as conn:  # the rows of earlier tables are untouched
            assert conn.execute(text("SELECT text FROM dprnt_lines")).scalars().all() == ["X 1.5"]
        migrate(engine)
        assert "status_samples" in inspect(engine).get_table_names()
    finally:
        engine.dispose()


def test_changes_only_are_stored_and_a_new_timeline_reads_them_back(
    sessions: sessionmaker[Session],
) -> None:
    tl = Timeline(sessions)
    assert note(tl, "m", T0, "READY")
    assert not note(tl, "m", T0 + timedelta(minutes=5), "READY")  # no change
    assert note(tl, "m", T0 + timedelta(hours=1), "ACTIVE")
    assert note(tl, "other", T0 + timedelta(hours=1), "", online=False)
    assert tl.flush() == 3
    assert tl.flush() == 0
    tl.stopped(T0 + timedelta(hours=2))  # the server stops ...
    assert tl.flush() == 2
    assert _rows(sessions) == [
        ("m", T0, "ready", "AUTOMATIC", "READY"),
        ("m", T0 + timedelta(hours=1), "running", "AUTOMATIC", "ACTIVE"),
        ("other", T0 + timedelta(hours=1), "offline", "", ""),
        ("m", T0 + timedelta(hours=2), "no_record", "", ""),
        ("other", T0 + timedelta(hours=2), "no_record", "", ""),
    ]

    # ... and starts again: a new timeline on the same database.
    again = Timeline(sessions)
    assert note(again, "m", T0 + timedelta(hours=3), "READY", "MANUAL")
    # Not yet written: the page sees it anyway.
    segments = again.segments("m", hours=4, width=400, now=T0 + timedelta(hours=4))
    assert [(s.x, s.width, s.state) for s in segments] == [
        (0.0, 100.0, "ready"),
        (100.0, 100.0, "running"),
        (200.0, 100.0, "no_record"),
        (300.0, 100.0, "ready"),
    ]
    assert [s.label for s in segments] == [
        "ready, automatic",
        "running, active, automatic",
        "no record (server stopped)",
        "ready, manual",
    ]
    again.flush()
    # A window that starts inside a stretch begins with the sample in force then.
    late = again.segments("m", hours=1, width=100, now=T0 + timedelta(hours=1, minutes=30))
    assert [(s.x, s.width, s.state) for s in late] == [
        (0.0, 50.0, "ready"),
        (50.0, 50.0, "running"),
    ]


def test_samples_older_than_the_retention_are_pruned(sessions: sessionmaker[Session]) -> None:
    now = T0 + timedelta(days=30)
    tl = Timeline(sessions)  # the default: 7 days
    note(tl, "m", now - timedelta(days=8), "READY")
    note(tl, "m", now - timedelta(days=6, hours=23), "ACTIVE")
    note(tl, "m", now - timedelta(hours=1), "READY")
    tl.flush()
    assert tl.prune(now) == 1
    assert [r[2] for r in _rows(sessions)] == ["running", "ready"]
    assert Timeline(sessions, retention_days=0.5).prune(now) == 1
    assert [r[2] for r in _rows(sessions)] == ["ready"]


def test_the_recorder_writes_bus_changes_and_marks_the_stop(
    sessions: sessionmaker[Session], engine: Engine
) -> None:
    async def scenario() -> None:
        bus = EventBus()
        bus.bind(asyncio.get_running_loop())
        tl = Timeline(sessions)
        async with running(tl, bus):
            bus.publish(_event("READY"))
            bus.publish(_event("READY"))  # a poll that changed nothing
            bus.publish(JobQueued(1, "m", JobKind.SEND, "O1", 1))  # not a state
            bus.publish(_event("ACTIVE"))
            deadline = time.monotonic() + 20
            while len(await asyncio.to_thread(_rows, sessions)) < 2:
                assert time.monotonic() < deadline, "the changes were never written"
                await asyncio.sleep(0.05)
        # Stopped: a "no_record" sample closes the record.
        assert [r[2] for r in _rows(sessions)] == ["ready", "running", "no_record"]

    asyncio.run(scenario())
    with engine.connect() as conn:
        assert conn.scalar(select(func.count()).select_from(StatusSample)) == 3


def test_the_retention_is_configured_in_days(tmp_path: Path) -> None:
    config = parse_config("[server]\ntimeline_retention_days = 2.5\n", base=tmp_path)
    assert config.server.timeline_days == 2.5
    assert parse_config("", base=tmp_path).server.timeline_days == 7.0
    for bad in ("0", "-1", '"7"', "true"):
        with pytest.raises(ConfigError) as caught:
            parse_config(f"[server]\ntimeline_retention_days = {bad}\n", base=tmp_path)
        assert caught.value.key == "server.timeline_retention_days"


def test_the_machine_page_timeline_survives_a_server_restart(tmp_path: Path, db_url: str) -> None:
    from opendnc.server.app import build
    from opendnc.server.outputs.parts import TimelineRecorder
    from opendnc.sim.fleet import server_config, start_fleet

    async def scenario() -> list[str]:
        fleet = await start_fleet(tmp_path / "machines", tnc=1, haas=0)
        try:
            text = server_config(fleet, poll_interval=0.3, library=tmp_path / "lib", check="warn")
            config = parse_config(text, base=tmp_path)
            first = build(config, database=db_url)
            async with first.app.router.lifespan_context(first.app):
                deadline = time.monotonic() + 30
                while "ready" not in [r[2] for r in await asyncio.to_thread(_rows, first.sessions)]:
                    assert time.monotonic() < deadline, "the TNC's state was never written"
                    await asyncio.sleep(0.1)
            first.engine.dispose()
            # A new server process would build anew: only the database carries the timeline.
            second = build(config, database=db_url)
            try:
                timeline = second.core.get(TimelineRecorder).timeline
                segments = await asyncio.to_thread(timeline.segments, "tnc-1", hours=1)
            finally:
                second.engine.dispose()
            return [s.state for s in segments]
        finally:
            await fleet.close()

    states = asyncio.run(scenario())
    assert "ready" in states
    assert states[-1] == "no_record"  # from the first server's stop until now


def test_a_database_that_is_away_keeps_the_samples_for_the_next_flush(
    sessions: sessionmaker[Session], engine: Engine
) -> None:
    tl = Timeline(sessions)
    note(tl, "m", T0, "READY")
    with engine.begin() as conn:  # the table is gone for a moment (a database being restored)
        conn.execute(text("ALTER TABLE status_samples RENAME TO status_samples_away"))
    try:
        assert tl.flush() == 0
        note(tl, "m", T0 + timedelta(minutes=1), "ACTIVE")
    finally:
        with engine.begin() as conn:
            conn.execute(text("ALTER TABLE status_samples_away RENAME TO status_samples"))
    assert tl.flush() == 2
    assert [r[2] for r in _rows(sessions)] == ["ready", "running"]  # in their order


def test_a_sample_the_database_cannot_hold_does_not_stop_the_recorder(
    sessions: sessionmaker[Session], caplog: pytest.LogCaptureFixture
) -> None:
    # A part count beyond the Integer column (SQLite's driver raised OverflowError, which
    # killed the recorder; PostgreSQL's DataError put the batch back to fail for ever) and a
    # program name no database encodes (a serial control's byte 0xFF, surrogate-escaped).
    def status(execution: str, program: str = "", parts: int | None = None) -> MachineStatus:
        return MachineStatus(
            at=T0, available=True, execution=execution, program=program, part_count=parts
        )

    async def scenario() -> None:
        bus = EventBus()
        bus.bind(asyncio.get_running_loop())
        tl = Timeline(sessions)
        async with running(tl, bus):
            bus.publish(MachineStatusChanged("a", True, status("READY")))
            bus.publish(MachineStatusChanged("b", True, status("READY", program="O\udcff1")))
            bus.publish(MachineStatusChanged("b", True, status("ACTIVE", parts=10**300)))
            bus.publish(MachineStatusChanged("c", True, status("ACTIVE", parts=3_000_000_000)))
            bus.publish(MachineStatusChanged("a", True, status("ACTIVE", parts=7)))
            deadline = time.monotonic() + 20
            while len(await asyncio.to_thread(_rows, sessions)) < 4:
                assert time.monotonic() < deadline, "the recorder stopped writing"
                await asyncio.sleep(0.05)
            # a later change still gets written: the recorder lives on
            bus.publish(MachineStatusChanged("c", True, status("READY")))
            while len(await asyncio.to_thread(_rows, sessions)) < 5:
                assert time.monotonic() < deadline, "the recorder stopped writing"
                await asyncio.sleep(0.05)

    with caplog.at_level("WARNING", logger="opendnc.server.machines.timeline"):
        asyncio.run(scenario())
    with sessions() as session:
        rows = session.scalars(select(StatusSample).order_by(StatusSample.id)).all()
        written = [(r.machine, r.state, r.part_count) for r in rows if r.state != "no_record"]
    assert written == [
        ("a", "ready", None),
        ("b", "running", None),  # the count the column cannot hold is unknown
        ("c", "running", None),
        ("a", "running", 7),
        ("c", "ready", None),
    ]
    dropped = [r.getMessage() for r in caplog.records if "dropped" in r.getMessage()]
    assert len(dropped) == 1, dropped
    assert "a sample of b" in dropped[0]
