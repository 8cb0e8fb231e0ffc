"""An alert episode is sent once across a restart and across the servers of a cluster: the
``alert_episodes`` row is the claim (docs/server.md#alerts). On PostgreSQL, with the aiosmtpd
sink of the alerts tests.

Knowing that nothing *more* was sent needs a marker: a failed job only that server hears of
(two servers have a bus each here, as in a cluster), and each server's target sends in order,
so once a server's marker is in, everything that server raised before it is in too.
"""

from __future__ import annotations

import asyncio
from collections.abc import Iterator
from datetime import timedelta

import pytest
from sqlalchemy import func, select
from sqlalchemy.orm import Session, sessionmaker

from opendnc.server.alerts.component import Alerts
from opendnc.server.core.events import EventBus, JobFinished, MachineStatusChanged
from opendnc.server.store.db import make_engine, make_sessions, migrate
from opendnc.server.store.models import AlertEpisode
from tests.server.alerts_support import SmtpPeer, smtp_server
from tests.server.conftest import _pg_database
from tests.server.test_alerts import BERLIN, NOON, Clock, config, reading, until

RULES = """
[[alerts.rules]]
name = "stop"
when = "stopped"
on_clear = true
[[alerts.rules]]
name = "jobs"
when = "job_failed"
"""


@pytest.fixture
def pg_sessions() -> Iterator[sessionmaker[Session]]:
    for url in _pg_database():
        engine = make_engine(url)
        try:
            migrate(engine)
            yield make_sessions(engine)
        finally:
            engine.dispose()


@pytest.fixture
def smtp() -> Iterator[SmtpPeer]:
    with smtp_server() as peer:
        yield peer


def _config(smtp: SmtpPeer) -> str:
    return f"""
[alerts]
backoff = 0.05
[alerts.email]
host = "127.0.0.1"
port = {smtp.port}
from = "dnc@shop.example"
to = ["lead@shop.example"]
{RULES}"""


def _subjects(smtp: SmtpPeer, server: str | None = None) -> list[str]:
    return [
        m.subject.removeprefix("[opendnc] ")
        for m in smtp.taken()
        if server is None or f"on server {server}." in m.text
    ]


def _marker(smtp: SmtpPeer, job: int, server: str) -> bool:
    return any(f"job {job} " in s for s in _subjects(smtp, server))


def _rows(sessions: sessionmaker[Session]) -> int:
    with sessions() as session:
        return int(session.scalar(select(func.count()).select_from(AlertEpisode)) or 0)


async def _component(
    cfg: str, sessions: sessionmaker[Session], bus: EventBus, server: str, clock: Clock
) -> Alerts:
    alerts = Alerts(config(cfg), bus, sessions, BERLIN, server, tick=0.05, clock=clock)
    await alerts.start()
    return alerts


def test_a_restarted_server_does_not_send_an_episode_again_and_sends_its_end_once(
    smtp: SmtpPeer, pg_sessions: sessionmaker[Session]
) -> None:
    cfg = _config(smtp)

    async def first() -> None:
        bus = EventBus()
        bus.bind(asyncio.get_running_loop())
        alerts = await _component(cfg, pg_sessions, bus, "dnc-1", Clock())
        try:
            bus.publish(reading("mill-1", "FEED_HOLD"))
            await until("the stop by mail", lambda: _subjects(smtp))
        finally:
            await asyncio.wait_for(alerts.stop(), 5)

    async def restarted() -> None:
        bus = EventBus()
        bus.bind(asyncio.get_running_loop())
        clock = Clock(NOON + timedelta(minutes=3))  # it sees the stop from its start on
        alerts = await _component(cfg, pg_sessions, bus, "dnc-1", clock)
        try:
            for _poll in range(3):
                bus.publish(reading("mill-1", "FEED_HOLD"))
            bus.publish(JobFinished(1, "mill-1", "send", "O1.nc", 1, outcome="failed"))
            await until("the marker", lambda: _marker(smtp, 1, "dnc-1"))
            clock.now = NOON + timedelta(minutes=7)
            bus.publish(reading("mill-1", "ACTIVE"))
            bus.publish(JobFinished(2, "mill-1", "send", "O1.nc", 1, outcome="failed"))
            await until("the second marker", lambda: _marker(smtp, 2, "dnc-1"))
        finally:
            await asyncio.wait_for(alerts.stop(), 5)

    asyncio.run(first())
    assert _rows(pg_sessions) == 1  # the episode, fired and not ended
    asyncio.run(restarted())
    stops = [s for s in _subjects(smtp) if "job" not in s]
    assert len(stops) == 2, stops
    assert stops[0] == "mill-1 stopped since 2026-07-01 14:00 (Europe/Berlin)"
    assert stops[1].startswith("mill-1 no longer stopped (was stopped since "), stops
    (end,) = [m for m in smtp.taken() if "no longer" in m.subject]
    # the end carries the episode's first start, as the first server saw it
    assert "Since:   2026-07-01 14:00:00 Europe/Berlin" in end.text
    assert _rows(pg_sessions) == 0


def test_two_servers_that_both_see_an_episode_send_it_once_and_its_end_once(
    smtp: SmtpPeer, pg_sessions: sessionmaker[Session]
) -> None:
    cfg = _config(smtp)

    async def both() -> None:
        loop = asyncio.get_running_loop()
        buses = {"dnc-1": EventBus(), "dnc-2": EventBus()}
        for bus in buses.values():
            bus.bind(loop)
        clock = Clock()
        one = await _component(cfg, pg_sessions, buses["dnc-1"], "dnc-1", clock)
        two = await _component(cfg, pg_sessions, buses["dnc-2"], "dnc-2", clock)

        def both_see(event: MachineStatusChanged) -> None:
            for bus in buses.values():
                bus.publish(event)

        async def markers(first: int) -> None:
            for job, (server, bus) in enumerate(buses.items(), start=first):
                bus.publish(JobFinished(job, "mill-1", "send", "O1.nc", 1, outcome="failed"))
                await until(f"{server}'s marker", lambda j=job, s=server: _marker(smtp, j, s))  # type: ignore[misc]

        try:
            for _poll in range(3):
                both_see(reading("mill-1", "FEED_HOLD"))
            await markers(1)
            clock.now = NOON + timedelta(minutes=7)
            both_see(reading("mill-1", "ACTIVE"))
            await markers(3)
        finally:
            await asyncio.wait_for(asyncio.gather(one.stop(), two.stop()), 5)

    asyncio.run(both())
    stops = [s for s in _subjects(smtp) if "job" not in s]
    assert len(stops) == 2, stops
    assert stops[0] == "mill-1 stopped since 2026-07-01 14:00 (Europe/Berlin)"
    assert stops[1].startswith("mill-1 no longer stopped")
    assert _rows(pg_sessions) == 0
