"""Status shared between the servers of a cluster, on the real PostgreSQL: a poll that read the
same status moves only its time, a change is written whole, a notice brings it to the other
server at once, a reader takes only what is new, and a machine that moved and came back is
shown with its server's status, never another's with its time."""

from __future__ import annotations

import asyncio
from collections.abc import Callable, Iterator
from dataclasses import replace
from datetime import UTC, datetime, timedelta
from pathlib import Path

import pytest
from sqlalchemy import select

from opendnc.server.config.shop import parse_config
from opendnc.server.core.events import EventBus
from opendnc.server.core.status import MachineStatus
from opendnc.server.fleet.shared_status import NOTICE, SharedStatus, status_from_json
from opendnc.server.machines.state import Machines, MachineState
from opendnc.server.store.db import make_engine, make_sessions, migrate
from opendnc.server.store.models import MachineLease, MachineSnapshot
from opendnc.server.store.notify import Listener, Notice
from tests.server.conftest import _pg_database

SHOP = "".join(
    f'[[machines]]\nname = "m{i}"\nkind = "lsv2"\nhost = "127.0.0.1"\nport = 1\n' for i in (1, 2, 3)
)


@pytest.fixture
def pg_url() -> Iterator[str]:
    yield from _pg_database()


def test_a_status_survives_its_json_whole() -> None:
    # every field set to something other than its default: one left out of as_json fails here
    status = MachineStatus(
        at=datetime(2026, 11, 28, 7, 1, 2, 345000, tzinfo=UTC),
        available=False,
        execution="ACTIVE",
        mode="AUTOMATIC",
        native_mode="MEM",
        program="O1234",
        line=17,
        part_count=5,
        tool=12,
        overrides={"feed": 80.0},
        errors=("E1", "E2"),
        message="refused",
        dprnt="PASS 1",
        dprnt_at=datetime(2026, 11, 28, 7, 0, 59, tzinfo=UTC),
    )
    assert set(status.as_json()) == set(MachineStatus.__dataclass_fields__)
    assert status_from_json(status.as_json()) == status


class Server:
    """One server's machines and its shared status, its ``served`` set by hand."""

    def __init__(self, name: str, url: str, tmp: Path, fallback: float) -> None:
        self.machines = Machines(parse_config(SHOP, base=tmp), EventBus())
        self.engine = make_engine(url)
        self.shared = SharedStatus(
            self.machines, make_sessions(self.engine), name, fallback=fallback
        )
        self.listener = Listener(url, self._notice)

    def _notice(self, notice: Notice) -> None:
        if notice.topic == NOTICE:  # as the cluster passes it on
            self.shared.wake(notice.key)

    def state(self, machine: str) -> MachineState:
        state = self.machines.get(machine)
        assert state is not None
        return state

    def serve(self, machine: str, served: bool) -> None:
        self.state(machine).served = served

    def poll(self, machine: str, at: datetime, execution: str = "READY") -> None:
        """A poll of ``machine`` here, as the fleet's task publishes it."""
        state = self.state(machine)
        state.online = True
        state.set_status(MachineStatus(at=at, available=True, execution=execution))
        self.machines.publish(state)


async def _until(what: str, condition: Callable[[], bool], timeout: float = 10.0) -> None:
    deadline = asyncio.get_running_loop().time() + timeout
    while not condition():
        assert asyncio.get_running_loop().time() < deadline, f"not in time: {what}"
        await asyncio.sleep(0.01)


def test_two_servers_share_statuses_by_notice_and_only_what_changed(
    pg_url: str, tmp_path: Path
) -> None:
    t0 = datetime.now(UTC)
    engine = make_engine(pg_url)
    migrate(engine)
    leases = make_sessions(engine)
    hour = timedelta(hours=1)

    def lease(machine: str, owner: str, expires: timedelta) -> None:
        with leases.begin() as session:
            session.merge(
                MachineLease(
                    machine=machine, owner=owner, epoch=1, acquired=t0, expires=t0 + expires
                )
            )

    lease("m1", "dnc-1", hour)
    lease("m2", "dnc-1", hour)
    lease("m3", "dnc-2", hour)

    async def scenario() -> None:
        # readers that read by themselves only every 30 s: whatever arrives sooner came by
        # the writer's notice
        a = Server("dnc-1", pg_url, tmp_path, fallback=30.0)
        b = Server("dnc-2", pg_url, tmp_path, fallback=30.0)
        for s in (a, b):
            for m in ("m1", "m2", "m3"):
                s.serve(m, False)
        a.serve("m1", True)
        a.serve("m2", True)
        b.serve("m3", True)
        tasks = [asyncio.create_task(s.listener.run()) for s in (a, b)]
        for s in (a, b):
            await asyncio.wait_for(s.listener.connected.wait(), 10)
            await s.machines.start()
            await s.shared.start()
        loop = asyncio.get_running_loop()
        try:
            a.poll("m1", t0)
            a.poll("m2", t0)
            b.poll("m3", t0)
            began = loop.time()
            await _until("m1 on dnc-2", lambda: b.state("m1").status is not None)
            await _until("m3 on dnc-1", lambda: a.state("m3").status is not None)
            assert loop.time() - began < 5  # by the notice, not the 30 s read
            assert b.state("m1").status == a.state("m1").status
            assert b.state("m1").online
            assert b.state("m1").served is False
            assert (a.shared.written, a.shared.touched) == (2, 0)

            # the same status read again: only its time moves, on the other server too
            reads = b.shared.reads
            a.poll("m1", t0 + timedelta(seconds=1))
            shown = b.state("m1")
            await _until("m1's new time", lambda: shown.status.at == t0 + timedelta(seconds=1))  # type: ignore[union-attr]
            assert (a.shared.written, a.shared.touched) == (2, 1)
            assert b.shared.reads > reads
            # a change is written whole
            a.poll("m1", t0 + timedelta(seconds=2), execution="ACTIVE")
            await _until("m1 running", lambda: shown.status.execution == "ACTIVE")  # type: ignore[union-attr]
            assert shown.status.at == t0 + timedelta(seconds=2)  # type: ignore[union-attr]
            assert a.shared.written == 3

            # a reader takes only what is new: nothing written, nothing applied again
            applied = b.shared.applied
            for _ in range(3):
                b.shared.wake()
                reads = b.shared.reads
                await _until("a read", lambda reads=reads: b.shared.reads > reads)  # type: ignore[misc]
            assert b.shared.applied == applied

            # m1 moves to dnc-2, which polls it (a different status) and writes it ...
            a.serve("m1", False)
            b.serve("m1", True)
            b.poll("m1", t0 + timedelta(seconds=3), execution="STOPPED")
            await _until("m1 stopped on dnc-1", lambda: a.state("m1").status.execution == "STOPPED")  # type: ignore[union-attr]
            # ... and comes back to dnc-1, whose poll reads what it last wrote: the row is
            # dnc-2's now, so it is written whole, not only its time
            b.serve("m1", False)
            a.serve("m1", True)
            a.poll("m1", t0 + timedelta(seconds=4), execution="ACTIVE")
            await _until("m1 running again", lambda: shown.status.execution == "ACTIVE")  # type: ignore[union-attr]
            assert shown.status.at == t0 + timedelta(seconds=4)  # type: ignore[union-attr]
            with a.shared.sessions() as session:
                row = session.scalars(
                    select(MachineSnapshot).where(MachineSnapshot.machine == "m1")
                ).one()
                assert (row.server, row.data["status"]["execution"]) == ("dnc-1", "ACTIVE")

            # dnc-2 holds m1 for a moment and lets it go before its first poll (its task
            # stopped: offline, as Fleet.release leaves it); dnc-1's next poll reads the same,
            # so only the time moves in the row, and yet dnc-2 shows m1 online again
            b.serve("m1", True)
            shown.online = False
            b.serve("m1", False)
            touched = a.shared.touched
            a.poll("m1", t0 + timedelta(seconds=4.5), execution="ACTIVE")
            await _until("m1 online again", lambda: shown.online)
            assert shown.status.at == t0 + timedelta(seconds=4.5)  # type: ignore[union-attr]
            assert a.shared.touched == touched + 1

            # dnc-2 serves m2 for a moment and polls it without writing (no write round in
            # between), then gives it back: dnc-1's next poll moves only the time in the
            # row, yet dnc-2 shows dnc-1's status, not its own with dnc-1's time
            b.serve("m2", True)
            mine = MachineStatus(at=t0 + timedelta(seconds=5), available=True, execution="STOPPED")
            b.state("m2").status = mine
            b.serve("m2", False)
            a.poll("m2", t0 + timedelta(seconds=6))
            seen = b.state("m2")
            await _until("m2's time", lambda: seen.status.at == t0 + timedelta(seconds=6))  # type: ignore[union-attr]
            assert seen.status == a.state("m2").status
            assert seen.status != replace(mine, at=seen.status.at)  # type: ignore[union-attr]

            # nobody holds m3 any more: dnc-1 says so; then dnc-2 holds it again and polls
            # the same status, so only its time moves, and dnc-1 shows it online again
            lease("m3", "dnc-2", -hour)
            m3 = a.state("m3")

            def orphaned() -> bool:
                a.shared.wake()  # (its reads look at the leases; this one reads only on notices)
                return not m3.online

            await _until("m3 orphaned", orphaned)
            assert m3.last_error == "no server serves this machine now"
            lease("m3", "dnc-2", hour)
            b.poll("m3", t0 + timedelta(seconds=7))
            await _until("m3 back", lambda: m3.online)
            assert m3.status == b.state("m3").status
            assert m3.last_error == ""
        finally:
            for s in (a, b):
                await s.shared.stop()
                s.engine.dispose()
            engine.dispose()
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)

    asyncio.run(scenario())
