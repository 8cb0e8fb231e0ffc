"""Alerts (docs/server.md#alerts): rules on the machines' states and the jobs' ends, sent to a
real SMTP server (aiosmtpd) and a real HTTP receiver on loopback, once per episode, each
delivery in the audit trail.

Most tests drive the alerts component in this process with events on a real bus (cheap and
exact: the clock is the test's); the last one runs the whole server around a virtual Haas."""

from __future__ import annotations

import asyncio
import hashlib
import hmac
import logging
import socket
import time
import tomllib
from collections.abc import Awaitable, Callable, Iterator
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any
from zoneinfo import ZoneInfo

import pytest
from sqlalchemy import select
from sqlalchemy.orm import Session, sessionmaker

from opendnc.server.alerts.component import Alerts
from opendnc.server.alerts.rules import AlertEngine, Phase
from opendnc.server.config.alerts import AlertKind, AlertsConfig, parse_alerts
from opendnc.server.config.shop import ConfigError, parse_config
from opendnc.server.core.events import EventBus, JobFinished, LeaseChanged, MachineStatusChanged
from opendnc.server.core.jobwords import JobKind, JobState
from opendnc.server.core.shifts import Calendar
from opendnc.server.core.status import MachineStatus
from opendnc.server.store.models import AuditEntry
from tests.server.alerts_support import (
    SmtpPeer,
    WebhookPeer,
    self_signed,
    smtp_server,
    webhook_receiver,
)
from tests.server.conftest import on
from tests.server.harness import free_port

BERLIN = Calendar(ZoneInfo("Europe/Berlin"))
NOON = datetime(2026, 7, 1, 12, 0, tzinfo=UTC)  # 14:00 in Berlin (CEST, UTC+2)
MACHINES = {"mill-1", "mill-2"}


def config(text: str) -> AlertsConfig:
    return parse_alerts(tomllib.loads(text)["alerts"], Path("."), MACHINES)


def reading(machine: str, execution: str, *, online: bool = True, errors: tuple[str, ...] = ()):  # type: ignore[no-untyped-def]
    status = MachineStatus(
        at=NOON, available=True, execution=execution, program="O01234", errors=errors
    )
    return MachineStatusChanged(machine, online, status if online else None, "no answer")


@dataclass
class Clock:
    now: datetime = NOON

    def __call__(self) -> datetime:
        return self.now


async def until(what: str, check: Callable[[], Any], timeout: float = 15) -> Any:
    """Poll ``check`` on the loop until true; fail naming ``what`` at the deadline."""
    end = time.monotonic() + timeout
    pause = 0.01
    while not (value := check()):
        if time.monotonic() > end:
            raise AssertionError(f"timed out waiting for {what}")
        await asyncio.sleep(pause)
        pause = min(0.1, pause * 1.5)
    return value


def run_alerts(
    cfg: AlertsConfig,
    sessions: sessionmaker[Session],
    scenario: Callable[[Alerts, EventBus, Clock], Awaitable[None]],
) -> None:
    """Start an alerts component on a bus, run ``scenario``, stop it."""

    async def main() -> None:
        bus, clock = EventBus(), Clock()
        bus.bind(asyncio.get_running_loop())
        alerts = Alerts(cfg, bus, sessions, BERLIN, "dnc-t", tick=0.05, clock=clock)
        await alerts.start()
        try:
            await scenario(alerts, bus, clock)
        finally:
            await asyncio.wait_for(alerts.stop(), 5)

    asyncio.run(main())


def audit_rows(sessions: sessionmaker[Session]) -> list[AuditEntry]:
    with sessions() as session:
        rows = session.scalars(
            select(AuditEntry).where(AuditEntry.action == "alert").order_by(AuditEntry.id)
        ).all()
        session.expunge_all()
        return list(rows)


def signature(secret: bytes, body: bytes) -> str:
    return "sha256=" + hmac.new(secret, body, hashlib.sha256).hexdigest()


@pytest.fixture
def smtp() -> Iterator[SmtpPeer]:
    with smtp_server() as peer:
        yield peer


@pytest.fixture
def hook() -> Iterator[WebhookPeer]:
    with webhook_receiver() as peer:
        yield peer


def targets(smtp: SmtpPeer, hook: WebhookPeer) -> str:
    return f"""
[alerts]
public_url = "https://dnc.example.com/"
backoff = 0.05
[alerts.email]
host = "127.0.0.1"
port = {smtp.port}
from = "dnc@shop.example"
to = ["lead@shop.example", "night@shop.example"]
[[alerts.webhooks]]
name = "ops"
url = "{hook.url}"
secret = "s3cret-hook"
"""


# -- the rules, in time the test sets -------------------------------------------------------


def test_a_stop_alerts_once_its_minutes_are_up_and_once_only() -> None:
    rules = config(
        '[alerts]\n[[alerts.webhooks]]\nname = "w"\nurl = "http://127.0.0.1:9/x"\n'
        '[[alerts.rules]]\nname = "long-stop"\nwhen = "stopped"\nminutes = 10\n'
        'machines = ["mill-1"]\n'
    ).rules
    engine = AlertEngine(rules)
    minute = timedelta(minutes=1)
    assert engine.status(reading("mill-1", "FEED_HOLD"), NOON) == []
    assert engine.tick(NOON + 9 * minute + timedelta(seconds=59)) == []
    assert engine.status(reading("mill-1", "FEED_HOLD"), NOON + 9 * minute) == []
    (fired,) = engine.tick(NOON + 10 * minute)
    assert (fired.phase, fired.machine, fired.since) == (Phase.FIRED, "mill-1", NOON)
    assert fired.detail == "FEED_HOLD, program O01234"
    # the stop goes on, poll after poll: nothing more
    for n in range(11, 30):
        assert engine.status(reading("mill-1", "STOPPED"), NOON + n * minute) == []
        assert engine.tick(NOON + n * minute) == []
    # a lost link is not the stop's end, so the link coming back raises nothing again
    assert engine.status(reading("mill-1", "", online=False), NOON + 31 * minute) == []
    assert engine.status(reading("mill-1", "FEED_HOLD"), NOON + 32 * minute) == []
    assert engine.tick(NOON + 60 * minute) == []
    # the end (no on_clear: silent), then a short stop (under its minutes: silent) ...
    assert engine.status(reading("mill-1", "ACTIVE"), NOON + 61 * minute) == []
    assert engine.status(reading("mill-1", "FEED_HOLD"), NOON + 62 * minute) == []
    assert engine.status(reading("mill-1", "ACTIVE"), NOON + 65 * minute) == []
    # ... and a second long stop: a second alert, since its own start
    engine.status(reading("mill-1", "FEED_HOLD"), NOON + 70 * minute)
    (second,) = engine.tick(NOON + 80 * minute)
    assert second.since == NOON + 70 * minute
    # another machine is not this rule's
    engine.status(reading("mill-2", "FEED_HOLD"), NOON)
    assert engine.tick(NOON + 120 * minute) == []


def test_alarm_offline_and_the_machines_of_another_server() -> None:
    rules = config(
        '[alerts]\n[[alerts.webhooks]]\nname = "w"\nurl = "http://127.0.0.1:9/x"\n'
        '[[alerts.rules]]\nname = "alarm"\nwhen = "alarm"\non_clear = true\n'
        '[[alerts.rules]]\nname = "gone"\nwhen = "offline"\nminutes = 5\n'
    ).rules
    engine = AlertEngine(rules)
    second = timedelta(seconds=1)
    (alarm,) = engine.status(reading("mill-2", "STOPPED", errors=("1010 SPINDLE",)), NOON)
    assert (alarm.rule.name, alarm.kind, alarm.detail) == ("alarm", AlertKind.ALARM, "1010 SPINDLE")
    assert engine.status(reading("mill-2", "STOPPED", errors=("1010 SPINDLE",)), NOON) == []
    (cleared,) = engine.status(reading("mill-2", "READY"), NOON + 60 * second)
    assert (cleared.phase, cleared.since, cleared.at) == (Phase.CLEARED, NOON, NOON + 60 * second)
    # offline for 4 minutes: nothing; then offline again for 5: one alert since then
    engine.status(reading("mill-1", "", online=False), NOON)
    assert engine.status(reading("mill-1", "READY"), NOON + 240 * second) == []
    engine.status(reading("mill-1", "", online=False), NOON + 300 * second)
    assert engine.tick(NOON + 599 * second) == []
    (gone,) = engine.tick(NOON + 600 * second)
    assert (gone.kind, gone.since, gone.detail) == (
        AlertKind.OFFLINE,
        NOON + 300 * second,
        "no answer",
    )
    # a machine another server serves now: its open episodes are that server's
    engine.status(reading("mill-2", "STOPPED", errors=("E",)), NOON)
    moved = MachineStatusChanged("mill-2", True, None, served=False)
    assert engine.status(moved, NOON) == []
    assert ("alarm", "mill-2") not in engine.open_episodes()
    # this server loses mill-1 (several servers): the offline reading its task's end leaves
    # is no outage, and its open episode is the new server's now
    engine.status(reading("mill-1", "", online=False), NOON + 700 * second)
    engine.lease(LeaseChanged("mill-1", "dnc-1", held=False))
    assert engine.open_episodes() == {}
    engine.status(reading("mill-1", "", online=False), NOON + 701 * second)
    assert engine.tick(NOON + 3600 * second) == []
    # gained again: its own readings count again
    engine.lease(LeaseChanged("mill-1", "dnc-1", held=True))
    engine.status(reading("mill-1", "", online=False), NOON + 3600 * second)
    assert [a.since for a in engine.tick(NOON + 3900 * second)] == [NOON + 3600 * second]


def test_the_configuration_names_the_bad_key_and_never_the_password(tmp_path: Path) -> None:
    base = '[alerts]\n[alerts.email]\nhost = "smtp.example.com"\nfrom = "a@b.example"\n'
    to = 'to = ["x@y.example"]\n'
    rule = to + '[[alerts.rules]]\nname = "r"\n'
    cases = {
        to: "alerts.rules: no rule",
        'to = ["not-an-address"]\n': "alerts.email.to[0]",
        to + 'username = "u"\npassword = "hunter2-pw"\n': "needs starttls or ssl",
        rule + 'when = "melted"\n': "alerts.rules[0].when",
        rule + 'when = "alarm"\nmachines = ["mill-9"]\n': "no machine named 'mill-9'",
        rule + 'when = "alarm"\nsend_to = ["pager"]\n': "no target 'pager'",
        rule + 'when = "job_failed"\nminutes = 3\n': "alerts.rules[0].minutes",
        rule + 'when = "alarm"\nrepeat = true\n': "alerts.rules[0].repeat: unknown key",
        to + '[[alerts.webhooks]]\nname = "w"\nurl = "http://127.0.0.1:99999/?t=hunter2-pw"\n': (
            "alerts.webhooks[0].url: expected a TCP port"
        ),
    }
    machine = '\n[[machines]]\nname = "mill-1"\nkind = "lsv2"\nhost = "127.0.0.1"\n'
    for extra, expected in cases.items():
        with pytest.raises(ConfigError) as caught:
            parse_config(machine + base + extra, base=tmp_path)
        assert expected in str(caught.value), extra
        assert "hunter2-pw" not in str(caught.value)
    good = parse_config(
        machine
        + '[alerts]\n[alerts.email]\nhost = "smtp.example.com"\nstarttls = true\n'
        + 'from = "a@b.example"\nto = "x@y.example"\nusername = "u"\npassword = "hunter2-pw"\n'
        + '[[alerts.rules]]\nname = "r"\nwhen = "alarm"\n',
        base=tmp_path,
    )
    assert good.alerts is not None
    assert good.alerts.email is not None
    assert (good.alerts.email.port, good.alerts.email.to) == (587, ("x@y.example",))
    assert good.alerts.email.password == "hunter2-pw"
    assert "hunter2-pw" not in repr(good)


def test_the_examples_in_the_readme_and_docs_are_valid(tmp_path: Path) -> None:
    repo = Path(__file__).resolve().parents[2]
    readme = (repo / "README.md").read_text(encoding="utf-8")
    block = readme.split("The configuration (docs/server.md", 1)[1]
    block = block.split("```text\n", 1)[1].split("```", 1)[0]
    shop = parse_config(block, base=tmp_path)
    assert shop.alerts is not None
    assert [r.kind for r in shop.alerts.rules] == [
        AlertKind.ALARM,
        AlertKind.STOPPED,
        AlertKind.JOB_FAILED,
    ]
    docs = (repo / "docs" / "server.md").read_text(encoding="utf-8").split("## Alerts", 1)[1]
    table = docs.split("```toml\n", 1)[1].split("```", 1)[0]
    machines = "".join(
        f'[[machines]]\nname = "{m}"\nkind = "lsv2"\nhost = "127.0.0.1"\n'
        for m in ("mill-1", "vf2")
    )
    documented = parse_config(machines + table, base=tmp_path).alerts
    assert documented is not None
    assert documented.email is not None
    assert documented.email.ca_file == tmp_path / "ca.pem"
    assert {r.name for r in documented.rules} == {"alarm", "long-stop", "jobs"}


# -- the component, with real peers --------------------------------------------------------


@on("sqlite")
def test_one_stop_through_several_polls_sends_one_message_a_second_stop_a_second(
    smtp: SmtpPeer, hook: WebhookPeer, sessions: sessionmaker[Session]
) -> None:
    cfg = config(
        targets(smtp, hook) + '[[alerts.rules]]\nname = "stop"\nwhen = "stopped"\non_clear = true\n'
    )

    async def scenario(alerts: Alerts, bus: EventBus, clock: Clock) -> None:
        bus.publish(reading("mill-1", "FEED_HOLD"))
        await until("the stop by mail", lambda: smtp.taken())
        for _poll in range(4):  # the stop goes on through four more polls
            bus.publish(reading("mill-1", "FEED_HOLD"))
            await asyncio.sleep(0.06)  # the rules' tick runs in between
        clock.now = NOON + timedelta(minutes=7)
        bus.publish(reading("mill-1", "ACTIVE"))  # it ends: the clear goes after the stop's
        await until("the stop and its end by mail", lambda: len(smtp.taken()) >= 2)
        await until("the stop and its end by webhook", lambda: len(hook.taken()) >= 2)
        assert len(smtp.taken()) == 2
        assert len(hook.taken()) == 2
        clock.now = NOON + timedelta(minutes=30)
        bus.publish(reading("mill-1", "FEED_HOLD"))
        bus.publish(reading("mill-1", "FEED_HOLD"))
        await until("the second stop by mail", lambda: len(smtp.taken()) >= 3)
        await until("the second stop by webhook", lambda: len(hook.taken()) >= 3)
        # a peer has the message a moment before the sender has its answer and audits it
        await until("six deliveries audited", lambda: len(audit_rows(sessions)) >= 6)

    run_alerts(cfg, sessions, scenario)
    first, end, second = smtp.taken()
    assert first.subject == "[opendnc] mill-1 stopped since 2026-07-01 14:00 (Europe/Berlin)"
    assert (first.sender, first.recipients) == (
        "dnc@shop.example",
        ["lead@shop.example", "night@shop.example"],
    )
    assert "Machine: mill-1" in first.text
    assert "Since:   2026-07-01 14:00:00 Europe/Berlin" in first.text
    assert "Detail:  FEED_HOLD, program O01234" in first.text
    assert "Page:    https://dnc.example.com/machines/mill-1" in first.text
    assert end.subject.startswith("[opendnc] mill-1 no longer stopped (was stopped since ")
    assert second.subject == "[opendnc] mill-1 stopped since 2026-07-01 14:30 (Europe/Berlin)"
    assert "Since:   2026-07-01 14:00:00 Europe/Berlin" in end.text
    assert "Until:   2026-07-01 14:07:00 Europe/Berlin" in end.text
    assert "Until:" not in first.text

    posts = hook.taken()
    for post in posts:
        assert post.headers["content-type"] == "application/json"
        assert post.headers["x-opendnc-signature"] == signature(b"s3cret-hook", post.body)
        assert post.path == "/hook"
    body = posts[0].json()
    assert body == {
        "version": 1,
        "server": "dnc-t",
        "rule": "stop",
        "kind": "stopped",
        "phase": "fired",
        "machine": "mill-1",
        "since": "2026-07-01T12:00:00+00:00",
        "since_local": "2026-07-01T14:00:00+02:00",
        "timezone": "Europe/Berlin",
        "at": "2026-07-01T12:00:00+00:00",
        "text": "mill-1 stopped since 2026-07-01 14:00 (Europe/Berlin)",
        "detail": "FEED_HOLD, program O01234",
        "job_id": None,
        "program": None,
        "url": "https://dnc.example.com/machines/mill-1",
    }
    assert [p.json()["phase"] for p in posts] == ["fired", "cleared", "fired"]
    assert (posts[1].json()["since"], posts[1].json()["at"]) == (
        "2026-07-01T12:00:00+00:00",
        "2026-07-01T12:07:00+00:00",
    )
    assert posts[2].json()["since"] == "2026-07-01T12:30:00+00:00"

    rows = audit_rows(sessions)
    assert len(rows) == 6
    assert {r.result for r in rows} == {"ok"}
    assert {r.machine for r in rows} == {"mill-1"}
    by_target = sorted((r.detail["target"], r.detail["phase"]) for r in rows)
    mail = f"email lead@shop.example,night@shop.example via 127.0.0.1:{smtp.port}"
    web = f"webhook ops (127.0.0.1:{hook.url.split(':')[2].split('/')[0]})"
    expected = [(t, p) for t in (mail, web) for p in ("fired", "cleared", "fired")]
    assert by_target == sorted(expected)


@on("sqlite")
def test_a_failed_job_sends_its_alert_once(
    smtp: SmtpPeer, hook: WebhookPeer, sessions: sessionmaker[Session]
) -> None:
    rules = '[[alerts.rules]]\nname = "jobs"\nwhen = "job_failed"\nmachines = ["mill-1"]\n'
    cfg = config(targets(smtp, hook) + rules)

    async def scenario(alerts: Alerts, bus: EventBus, clock: Clock) -> None:
        error = "TNC:/nc_prog/O01234.nc: the control refused the file"
        bus.publish(
            JobFinished(
                7, "mill-1", JobKind.SEND, "O01234.nc", 2, outcome=JobState.FAILED, error=error
            )
        )
        bus.publish(
            JobFinished(
                7, "mill-1", JobKind.SEND, "O01234.nc", 2, outcome=JobState.FAILED, error=error
            )
        )
        bus.publish(
            JobFinished(8, "mill-1", JobKind.SEND, "O01234.nc", 2, outcome=JobState.CANCELLED)
        )
        bus.publish(JobFinished(9, "mill-1", JobKind.SEND, "O01234.nc", 2, outcome=JobState.QUEUED))
        bus.publish(
            JobFinished(10, "mill-2", JobKind.SEND, "O01234.nc", 2, outcome=JobState.FAILED)
        )
        bus.publish(
            JobFinished(11, "mill-1", JobKind.DRIPFEED, "O7.nc", 1, outcome=JobState.INTERRUPTED)
        )
        await until("two job alerts by mail", lambda: len(smtp.taken()) >= 2)
        await until("two job alerts by webhook", lambda: len(hook.taken()) >= 2)
        await until("four deliveries audited", lambda: len(audit_rows(sessions)) >= 4)

    run_alerts(cfg, sessions, scenario)
    mails = smtp.taken()
    assert [m.subject for m in mails] == [
        "[opendnc] mill-1: job 7 (O01234.nc) failed at 2026-07-01 14:00 (Europe/Berlin)",
        "[opendnc] mill-1: job 11 (O7.nc) failed at 2026-07-01 14:00 (Europe/Berlin)",
    ]
    assert "Detail:  TNC:/nc_prog/O01234.nc: the control refused the file" in mails[0].text
    assert "Job:     7 (O01234.nc)" in mails[0].text
    assert [(p.json()["job_id"], p.json()["kind"]) for p in hook.taken()] == [
        (7, "job_failed"),
        (11, "job_failed"),
    ]
    assert sorted(r.job_id or 0 for r in audit_rows(sessions)) == [7, 7, 11, 11]


@on("sqlite")
def test_a_dead_target_is_audited_as_failed_logged_once_and_holds_nothing_up(
    hook: WebhookPeer, sessions: sessionmaker[Session], caplog: pytest.LogCaptureFixture
) -> None:
    dead = free_port()  # nothing listens there
    # an SMTP server that takes the connection and never says a word (closed at the end,
    # which ends the sender's wait)
    silent = socket.create_server(("127.0.0.1", 0))
    silent_port = silent.getsockname()[1]
    hook.fail_next = 1  # the good webhook fails once: its retry gets through
    cfg = config(f"""
[alerts]
backoff = 0.05
[alerts.email]
host = "127.0.0.1"
port = {silent_port}
from = "dnc@shop.example"
to = ["lead@shop.example"]
timeout = 20
[[alerts.webhooks]]
name = "dead"
url = "http://127.0.0.1:{dead}/hook"
retries = 1
[[alerts.webhooks]]
name = "ops"
url = "{hook.url}"
secret = "plain-token"
sign = "header"
[[alerts.rules]]
name = "alarm"
when = "alarm"
""")

    async def scenario(alerts: Alerts, bus: EventBus, clock: Clock) -> None:
        bus.publish(reading("mill-1", "STOPPED", errors=("1010",)))
        bus.publish(reading("mill-2", "STOPPED", errors=("1011",)))
        await until("both alarms by webhook", lambda: len(hook.taken()) >= 3)
        await until("four webhook deliveries audited", lambda: len(audit_rows(sessions)) >= 4)

    with caplog.at_level(logging.WARNING, logger="opendnc.server.alerts.component"), silent:
        run_alerts(cfg, sessions, scenario)
    posts = hook.taken()
    assert [p.json()["machine"] for p in posts] == ["mill-1", "mill-1", "mill-2"]  # a retry
    assert all(p.headers["x-opendnc-secret"] == "plain-token" for p in posts)
    rows = audit_rows(sessions)
    # the webhooks did not wait for the SMTP server, which has not answered yet
    assert all(r.detail["target"].startswith("webhook ") for r in rows), rows
    failed = sorted(
        (r.machine, r.detail["target"], r.detail["attempts"]) for r in rows if r.result == "failed"
    )
    assert failed == [(m, f"webhook dead (127.0.0.1:{dead})", 2) for m in ("mill-1", "mill-2")]
    assert all("ConnectError" in r.detail["error"] for r in rows if r.result == "failed")
    ok = [r for r in rows if r.result == "ok"]
    assert sorted((r.machine, r.detail["attempts"]) for r in ok) == [("mill-1", 2), ("mill-2", 1)]
    # one warning for the outage, not one per message
    down = [r.getMessage() for r in caplog.records if "not reachable" in r.getMessage()]
    assert len(down) == 1, down
    assert f"webhook dead (127.0.0.1:{dead})" in down[0]
    assert "plain-token" not in caplog.text


@on("sqlite")
def test_starttls_and_login_and_the_password_never_shows(
    tmp_path: Path, sessions: sessionmaker[Session], caplog: pytest.LogCaptureFixture
) -> None:
    cert, key = self_signed(tmp_path)
    right, wrong = "pw-Right-42", "pw-Wrong-43"
    with (
        smtp_server(tls=(cert, key), users={"dnc": right}) as smtp,
        caplog.at_level(logging.DEBUG, logger="opendnc"),
    ):
        for n, password in enumerate((right, wrong), start=1):
            cfg = config(f"""
[alerts]
[alerts.email]
host = "127.0.0.1"
port = {smtp.port}
starttls = true
ca_file = "{cert}"
username = "dnc"
password = "{password}"
from = "dnc@shop.example"
to = ["lead@shop.example"]
retries = 0
[[alerts.rules]]
name = "alarm"
when = "alarm"
""")
            assert password not in repr(cfg)

            async def scenario(alerts: Alerts, bus: EventBus, clock: Clock, n: int = n) -> None:
                # a machine each: one machine's alarm, still on, is not sent again (its
                # episode is in the database)
                bus.publish(reading(f"mill-{n}", "STOPPED", errors=("1010",)))
                await until("the delivery audited", lambda: len(audit_rows(sessions)) >= n)

            run_alerts(cfg, sessions, scenario)
    (mail,) = smtp.taken()  # the right login only
    assert mail.login == "dnc"
    # both were tried (smtplib tries a refused login by each mechanism the server offers)
    assert set(smtp.logins) == {("dnc", right), ("dnc", wrong)}
    sent, refused = audit_rows(sessions)
    assert (sent.result, refused.result) == ("ok", "failed")
    assert "535" in refused.detail["error"]  # the server's answer: credentials invalid
    for row in (sent, refused):
        assert right not in repr(row.detail)
        assert wrong not in repr(row.detail)
    assert "not reachable" in caplog.text
    assert right not in caplog.text
    assert wrong not in caplog.text

    # SMTP over TLS from the start (port 465's way), the certificate checked against ca_file
    with smtp_server(tls=(cert, key), implicit=True) as smtps:
        cfg = config(f"""
[alerts]
[alerts.email]
host = "127.0.0.1"
port = {smtps.port}
ssl = true
ca_file = "{cert}"
from = "dnc@shop.example"
to = ["lead@shop.example"]
retries = 0
[[alerts.rules]]
name = "alarm"
when = "alarm"
""")

        async def over_tls(alerts: Alerts, bus: EventBus, clock: Clock) -> None:
            bus.publish(reading("mill-3", "STOPPED", errors=("1010",)))
            await until("the delivery audited", lambda: len(audit_rows(sessions)) >= 3)

        run_alerts(cfg, sessions, over_tls)
    (mail,) = smtps.taken()
    assert audit_rows(sessions)[-1].result == "ok"
    assert mail.subject.startswith("[opendnc] mill-3 in alarm since ")


# -- the whole server ----------------------------------------------------------------------


def test_the_server_alerts_once_per_stop_of_a_virtual_haas_and_for_a_failed_job(
    tmp_path: Path, smtp: SmtpPeer, hook: WebhookPeer
) -> None:
    from opendnc.server.access import auth
    from opendnc.server.app import build
    from opendnc.server.store.models import Role
    from opendnc.sim.fleet import server_config
    from opendnc.sim.haas.machine import Status
    from tests.server.harness import httpx, wait_for
    from tests.server.serving import serving
    from tests.server.test_from_the_control import FleetThread

    ngc = FleetThread(tmp_path / "machines", tnc=0, haas=1)
    dead = free_port()  # a webhook nobody listens to
    hung = socket.create_server(("127.0.0.1", 0))  # one that takes the request, never answers
    try:
        text = server_config(
            ngc.fleet, poll_interval=0.2, library=tmp_path / "lib", timezone="Europe/Berlin"
        )
        hung_url = f"http://127.0.0.1:{hung.getsockname()[1]}/"
        text += targets(smtp, hook) + (
            f'[[alerts.webhooks]]\nname = "dead"\nurl = "http://127.0.0.1:{dead}/"\nretries = 0\n'
            f'[[alerts.webhooks]]\nname = "hung"\nurl = "{hung_url}"\ntimeout = 60\n'
            '[[alerts.rules]]\nname = "stop"\nwhen = "stopped"\non_clear = true\n'
            '[[alerts.rules]]\nname = "jobs"\nwhen = "job_failed"\nsend_to = ["email", "ops"]\n'
        )
        server = build(
            parse_config(text, base=tmp_path), database=f"sqlite:///{tmp_path / 'db.sqlite'}"
        )
        assert server.core.find(Alerts) is not None
        with server.sessions.begin() as session:
            auth.create_user(session, "admin", Role.ADMIN)
            key = auth.create_key(session, "admin", Role.ADMIN, label="test")[1]
        headers = {"Authorization": f"Bearer {key}"}
        machine = server.machines.machines["haas-1"]
        control = ngc.fleet.sims["haas-1"].control.machine

        def hold(status: Any) -> None:
            ngc.call(lambda: setattr(control, "status", status))

        with serving(server) as url, httpx.Client(base_url=url, timeout=30) as client:
            wait_for("the Haas online", lambda: machine.status is not None)
            before = datetime.now(UTC)
            hold(Status.FEED_HOLD)  # the operator presses feed hold
            wait_for("the stop by mail", lambda: smtp.taken())
            arrived = datetime.now(UTC)
            # the stop lasts through several more polls (every 0.2 s) ...
            wait_for(
                "three more polls of the stopped Haas",
                lambda: (
                    machine.status is not None
                    and machine.status.at > arrived + timedelta(seconds=0.6)
                    and machine.status.execution == "FEED_HOLD"
                ),
            )
            hold(Status.IDLE)  # ... and ends: its end is the next message, nothing between
            wait_for("the end of the stop by mail", lambda: len(smtp.taken()) >= 2)
            hold(Status.FEED_HOLD)  # a second stop: a second message
            wait_for("the second stop by mail", lambda: len(smtp.taken()) >= 3)

            job = client.post(
                "/api/jobs",
                headers=headers,
                json={"kind": "receive", "path": "O09999.nc", "machines": ["haas-1"]},
            ).json()[0]
            wait_for("the job's alert by mail", lambda: len(smtp.taken()) >= 4)
            wait_for("every alert by webhook", lambda: len(hook.taken()) >= 4)
            state = client.get(f"/api/jobs/{job['id']}", headers=headers).json()
            assert state["state"] == "failed"
            audited = wait_for(
                "eleven deliveries audited",
                lambda: (
                    (
                        rows := client.get(
                            "/api/audit", headers=headers, params={"action": "alert"}
                        ).json()
                    )
                    and len(rows) >= 11
                    and rows
                ),
            )
            # the machine's task went on polling all along, the hung webhook notwithstanding
            assert machine.status is not None
            assert machine.status.at > datetime.now(UTC) - timedelta(seconds=5)
            # what a viewer sees of the targets, and the second stop still open
            assert client.get("/api/alerts").status_code == 401
            seen = client.get("/api/alerts", headers=headers).json()
            assert seen["configured"] is True
            assert [(t["name"], t["reachable"], t["queued"]) for t in seen["targets"]] == [
                ("email", True, 0),
                ("ops", True, 0),
                ("dead", False, 0),
                ("hung", True, 2),  # the first stop still in flight; its end and the next wait
            ]
            assert [(e["rule"], e["machine"]) for e in seen["open"]] == [("stop", "haas-1")]

        mails = smtp.taken()
        assert len(mails) == 4
        stop, end, again, failed = mails
        assert stop.subject.startswith("[opendnc] haas-1 stopped since ")
        assert end.subject.startswith("[opendnc] haas-1 no longer stopped (was stopped")
        assert again.subject.startswith("[opendnc] haas-1 stopped since ")
        assert f"job {job['id']} failed" in failed.subject
        assert "cannot read O09999.nc" in failed.text
        posts = [p.json() for p in hook.taken()]
        assert [(p["rule"], p["phase"]) for p in posts] == [
            ("stop", "fired"),
            ("stop", "cleared"),
            ("stop", "fired"),
            ("jobs", "fired"),
        ]
        # the stop began between the feed hold and the message; the mail says it in Berlin
        since = datetime.fromisoformat(posts[0]["since"])
        assert before <= since <= arrived
        local = since.astimezone(ZoneInfo("Europe/Berlin"))
        assert stop.subject.endswith(f"since {local:%Y-%m-%d %H:%M} (Europe/Berlin)")
        assert posts[0]["url"] == "https://dnc.example.com/machines/haas-1"
        # newest first: the dead webhook's three failures (the stops'; the job's rule names
        # only email and ops), the others' eight deliveries, the hung one's none yet
        failed_rows = [row for row in audited if row["result"] != "ok"]
        assert [
            (r["result"], r["detail"]["target"], r["detail"]["phase"]) for r in failed_rows
        ] == [
            ("failed", f"webhook dead (127.0.0.1:{dead})", phase)
            for phase in ("fired", "cleared", "fired")
        ]
        assert all("ConnectError" in r["detail"]["error"] for r in failed_rows)
        ok = [row["detail"]["target"].split()[0:2] for row in audited if row["result"] == "ok"]
        assert sorted(name for kind, name in ok if kind == "webhook") == ["ops"] * 4
        assert len([1 for kind, _name in ok if kind == "email"]) == 4
        assert not [row for row in audited if "hung" in row["detail"]["target"]]
        assert sorted(row["job_id"] or 0 for row in audited)[-2:] == [job["id"], job["id"]]
    finally:
        hung.close()
        ngc.stop()


def test_the_alerts_test_command_sends_to_each_target_and_says_how_it_went(
    tmp_path: Path, smtp: SmtpPeer, hook: WebhookPeer
) -> None:
    from typer.testing import CliRunner

    from opendnc.cli.main import app

    dead = free_port()
    shop = tmp_path / "shop.toml"
    shop.write_text(
        '[[machines]]\nname = "mill-1"\nkind = "lsv2"\nhost = "127.0.0.1"\n'
        + targets(smtp, hook)
        + f'[[alerts.webhooks]]\nname = "dead"\nurl = "http://127.0.0.1:{dead}/"\nretries = 0\n'
        + '[[alerts.rules]]\nname = "alarm"\nwhen = "alarm"\n',
        encoding="utf-8",
    )
    runner = CliRunner()
    result = runner.invoke(app, ["alerts", "test", "--config", str(shop), "--to", "ops"])
    assert result.exit_code == 0, result.output
    assert result.output.startswith("sent    webhook ops (127.0.0.1:")
    (post,) = hook.taken()
    assert (post.json()["machine"], post.json()["kind"], post.json()["rule"]) == (
        "mill-1",
        "alarm",
        "test",
    )
    assert post.headers["x-opendnc-signature"] == signature(b"s3cret-hook", post.body)
    assert smtp.taken() == []  # only the target asked for

    result = runner.invoke(app, ["alerts", "test", "--config", str(shop)])
    assert result.exit_code == 1
    lines = result.output.splitlines()
    assert lines[0].startswith("sent    email lead@shop.example,night@shop.example via ")
    assert lines[1].startswith("sent    webhook ops")
    assert lines[2].startswith(f"failed  webhook dead (127.0.0.1:{dead}): ConnectError")
    assert len(smtp.taken()) == 1
    assert smtp.taken()[0].subject.startswith("[opendnc] mill-1 in alarm since ")

    result = runner.invoke(app, ["alerts", "test", "--config", str(shop), "--to", "pager"])
    assert result.exit_code == 1
    assert "no target 'pager' (have dead, email, ops)" in result.output
