"""A failed job's alert goes once across the servers of a cluster and across a restart: each
failed job is claimed in ``alerted_jobs`` before its alerts go (docs/server.md#alerts). On
SQLite and on PostgreSQL, with a real SMTP server (aiosmtpd) and a real webhook receiver on
loopback.

Knowing that nothing *more* was sent needs a marker per server: a failed job only that server
hears of. Each target of a server sends in order, so once a server's marker is in at a
target, everything that server raised before it is in there too.
"""

from __future__ import annotations

import asyncio
from collections import Counter
from collections.abc import Iterator

import pytest
from sqlalchemy import select
from sqlalchemy.exc import IntegrityError, OperationalError
from sqlalchemy.orm import Session, sessionmaker

from opendnc.server.alerts import component
from opendnc.server.alerts.component import Alerts
from opendnc.server.core.events import EventBus, JobFinished
from opendnc.server.core.jobwords import JobKind, JobState
from opendnc.server.store.claims import claim_once
from opendnc.server.store.models import AlertedJob
from tests.server.alerts_support import SmtpPeer, WebhookPeer, smtp_server, webhook_receiver
from tests.server.test_alerts import BERLIN, Clock, audit_rows, config, until

FAILED = (1, 2, 3)  # the jobs every server hears of


@pytest.fixture
def smtp() -> Iterator[SmtpPeer]:
    with smtp_server() as peer:
        yield peer


@pytest.fixture
def hook() -> Iterator[WebhookPeer]:
    with webhook_receiver() as peer:
        yield peer


def _config(smtp: SmtpPeer, hook: WebhookPeer) -> str:
    return f"""
[alerts]
backoff = 0.05
[alerts.email]
host = "127.0.0.1"
port = {smtp.port}
from = "dnc@shop.example"
to = ["lead@shop.example"]
[[alerts.webhooks]]
name = "ops"
url = "{hook.url}"
[[alerts.rules]]
name = "jobs"
when = "job_failed"
"""


def _failed(job: int) -> JobFinished:
    return JobFinished(
        job, "mill-1", JobKind.SEND, "O1.nc", 1, outcome=JobState.FAILED, error="no answer"
    )


def _mailed(smtp: SmtpPeer) -> Counter[tuple[int, str]]:
    """(job, server) of each mail: the subject names the job, the text the server."""
    out: Counter[tuple[int, str]] = Counter()
    for mail in smtp.taken():
        for line in mail.text.splitlines():
            if line.startswith("Job:"):
                server = mail.text.split("on server ", 1)[1].split(".", 1)[0]
                out[(int(line.split()[1]), server)] += 1
    return out


def _posted(hook: WebhookPeer) -> Counter[tuple[int, str]]:
    """(job, server) of each webhook."""
    return Counter((p.json()["job_id"], p.json()["server"]) for p in hook.taken())


def _jobs(counts: Counter[tuple[int, str]]) -> Counter[int]:
    out: Counter[int] = Counter()
    for (job, _server), n in counts.items():
        out[job] += n
    return out


async def _servers(
    cfg: str,
    sessions: sessionmaker[Session],
    smtp: SmtpPeer,
    hook: WebhookPeer,
    names: tuple[str, ...],
    marker: int,
) -> None:
    """Start one alerts component per name (a bus each, as in a cluster), tell every one of
    the jobs of FAILED (twice), then one marker job to each alone and wait for every marker
    at both targets."""
    loop = asyncio.get_running_loop()
    running: list[Alerts] = []
    try:
        buses: dict[str, EventBus] = {}
        for name in names:
            bus = buses[name] = EventBus()
            bus.bind(loop)
            alerts = Alerts(config(cfg), bus, sessions, BERLIN, name, tick=0.05, clock=Clock())
            await alerts.start()
            running.append(alerts)
        for job in FAILED + FAILED:
            for bus in buses.values():
                bus.publish(_failed(job))
        for job, (name, bus) in enumerate(buses.items(), start=marker):
            bus.publish(_failed(job))
            key = (job, name)
            await until(f"{name}'s marker by mail", lambda k=key: _mailed(smtp)[k])  # type: ignore[misc]
            await until(f"{name}'s marker by webhook", lambda k=key: _posted(hook)[k])  # type: ignore[misc]
            # each delivery's audit row is written after it: the marker's rows come last
            await until(
                f"{name}'s marker audited",
                lambda j=job: sum(r.job_id == j for r in audit_rows(sessions)) == 2,  # type: ignore[misc]
            )
    finally:
        await asyncio.wait_for(asyncio.gather(*(a.stop() for a in running)), 5)


def _claims(sessions: sessionmaker[Session]) -> dict[int, str]:
    with sessions() as session:
        return {r.job_id: r.server for r in session.scalars(select(AlertedJob))}


def test_two_servers_send_one_mail_and_one_webhook_per_failed_job_and_a_restart_none(
    smtp: SmtpPeer, hook: WebhookPeer, sessions: sessionmaker[Session]
) -> None:
    cfg = _config(smtp, hook)
    asyncio.run(_servers(cfg, sessions, smtp, hook, ("dnc-1", "dnc-2"), marker=101))
    want = Counter({1: 1, 2: 1, 3: 1, 101: 1, 102: 1})
    assert _jobs(_mailed(smtp)) == want
    assert _jobs(_posted(hook)) == want
    claims = _claims(sessions)
    assert set(claims) == {1, 2, 3, 101, 102}
    # the one that claimed a job is the one that sent it, by mail and by webhook
    for job in FAILED:
        assert (job, claims[job]) in _mailed(smtp)
        assert (job, claims[job]) in _posted(hook)
    # one audit row per delivery: each job's mail and webhook, from its claimer
    rows = Counter((r.job_id, r.result) for r in audit_rows(sessions))
    assert rows == Counter({(job, "ok"): 2 for job in want})

    # dnc-1 restarted (nothing of the jobs in memory) hears of the same failed jobs again
    asyncio.run(_servers(cfg, sessions, smtp, hook, ("dnc-1",), marker=103))
    want[103] = 1
    assert _jobs(_mailed(smtp)) == want
    assert _jobs(_posted(hook)) == want


def test_a_claim_left_by_a_server_killed_mid_send_is_not_sent_again(
    smtp: SmtpPeer, hook: WebhookPeer, sessions: sessionmaker[Session]
) -> None:
    # the dead server claimed job 2 and died before its alerts went: at most once
    assert claim_once(sessions, AlertedJob(job_id=2, machine="mill-1", server="dnc-dead"))
    asyncio.run(_servers(_config(smtp, hook), sessions, smtp, hook, ("dnc-1",), marker=101))
    want = Counter({1: 1, 3: 1, 101: 1})
    assert _jobs(_mailed(smtp)) == want
    assert _jobs(_posted(hook)) == want
    assert _claims(sessions)[2] == "dnc-dead"


def test_claim_once_lets_one_insert_through_and_does_not_hide_a_bad_row(
    sessions: sessionmaker[Session],
) -> None:
    assert claim_once(sessions, AlertedJob(job_id=7, machine="mill-1", server="dnc-1"))
    assert not claim_once(sessions, AlertedJob(job_id=7, machine="mill-1", server="dnc-2"))
    assert _claims(sessions) == {7: "dnc-1"}
    with pytest.raises(IntegrityError):  # refused for a NULL, not for a claim: a bug shows
        claim_once(sessions, AlertedJob(job_id=8, machine=None, server="dnc-1"))


def test_a_job_alerted_during_an_outage_is_claimed_once_the_database_answers(
    smtp: SmtpPeer,
    hook: WebhookPeer,
    sessions: sessionmaker[Session],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    real = claim_once
    away = {"yes": True}

    def flaky(s: sessionmaker[Session], row: AlertedJob) -> bool:
        if away["yes"]:
            raise OperationalError("INSERT", {}, ConnectionRefusedError("refused"))
        return real(s, row)

    monkeypatch.setattr(component, "claim_once", flaky)
    monkeypatch.setattr(component, "CLAIM_RETRY", 0.0)

    async def scenario() -> None:
        bus = EventBus()
        bus.bind(asyncio.get_running_loop())
        alerts = Alerts(
            config(_config(smtp, hook)), bus, sessions, BERLIN, "dnc-1", tick=0.05, clock=Clock()
        )
        await alerts.start()
        try:
            bus.publish(_failed(5))  # sent without its claim: a duplicate beats a lost alert
            await until("the mail", lambda: _mailed(smtp)[(5, "dnc-1")])
            await until("the webhook", lambda: _posted(hook)[(5, "dnc-1")])
            assert _claims(sessions) == {}
            away["yes"] = False
            await until("the claim written late", lambda: _claims(sessions) == {5: "dnc-1"})
        finally:
            await asyncio.wait_for(alerts.stop(), 5)

    asyncio.run(scenario())
    # the claim is there now: another server (or this one restarted) does not send job 5
    asyncio.run(_servers(_config(smtp, hook), sessions, smtp, hook, ("dnc-2",), marker=101))
    assert _jobs(_mailed(smtp))[5] == 1
    assert _jobs(_posted(hook))[5] == 1
