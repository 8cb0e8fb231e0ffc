"""The shift report is mailed once per shift end across the servers of a cluster and across a
restart: each report is claimed in ``shift_reports`` before it is built and sent. A server
killed mid-send leaves the claim at ``sending``, and that report is not sent again. On
PostgreSQL (the cluster's database), with a real local SMTP server (aiosmtpd)."""

from __future__ import annotations

import asyncio
import os
import subprocess
import sys
import textwrap
import threading
from collections.abc import Iterator
from datetime import date, timedelta
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import select
from sqlalchemy.orm import Session, sessionmaker

from opendnc.server.config.alerts import EmailTarget
from opendnc.server.config.shop import ShopConfig, parse_config
from opendnc.server.reports.mail import ShiftMailer, due
from opendnc.server.reports.shift import shift_period
from opendnc.server.store.db import make_engine, make_sessions, migrate
from opendnc.server.store.models import AuditEntry, ShiftReportSent
from tests.server.alerts_support import smtp_server
from tests.server.conftest import _pg_database
from tests.server.harness import free_port, wait_for
from tests.web.utilization_shop import CONFIG, local, write_timeline

AFTER = local(23)  # the early (06-14) and late (14-22) shifts of Monday are over


@pytest.fixture
def pg() -> Iterator[tuple[str, sessionmaker[Session]]]:
    for url in _pg_database():
        engine = make_engine(url)
        try:
            migrate(engine)
            yield url, make_sessions(engine)
        finally:
            engine.dispose()


def _config(tmp_path: Path, name: str) -> ShopConfig:
    return parse_config(CONFIG.replace('bind = "127.0.0.1:0"', f'name = "{name}"'), base=tmp_path)


def _target(port: int) -> EmailTarget:
    return EmailTarget(host="127.0.0.1", port=port, sender="dnc@shop.test",
                       to=("lead@shop.test",), timeout=5.0)  # fmt: skip


def _rows(sessions: sessionmaker[Session]) -> list[tuple[str, str, str]]:
    with sessions() as session:
        rows = session.scalars(select(ShiftReportSent).order_by(ShiftReportSent.shift))
        return [(r.shift, r.state, r.server) for r in rows]


def test_two_servers_and_a_restart_send_one_report(
    pg: tuple[str, sessionmaker[Session]], tmp_path: Path
) -> None:
    _url, sessions = pg
    write_timeline(sessions)
    period = shift_period(_config(tmp_path, "a"), date(2026, 1, 5), "early")
    with smtp_server() as peer:
        mailers = [ShiftMailer(sessions, _config(tmp_path, n), _target(peer.port)) for n in "ab"]
        results: dict[str, bool] = {}
        start = threading.Barrier(2)

        def send(m: ShiftMailer) -> None:
            start.wait()  # both at the shift's end at once, as two servers of a cluster are
            results[m.config.server.name] = m.send(period, AFTER)

        threads = [threading.Thread(target=send, args=(m,)) for m in mailers]
        for t in threads:
            t.start()
        for t in threads:
            t.join(30)
        assert sorted(results.values()) == [False, True]
        winner = next(n for n, sent in results.items() if sent)
        # a restarted server (a new mailer on the same database) does not send it again
        again = ShiftMailer(sessions, _config(tmp_path, winner), _target(peer.port))
        assert not again.send(period, AFTER)
        mail = peer.taken()
    assert [m.subject for m in mail] == [
        f"[opendnc] Shift report on {winner}: early of Mon 05 Jan 2026"
    ]
    assert _rows(sessions) == [("2026-01-05 early", "sent", winner)]
    with sessions() as session:
        audited = session.scalars(select(AuditEntry).where(AuditEntry.action == "report.shift"))
        assert [(a.result, a.detail["shift"]) for a in audited] == [("ok", "2026-01-05 early")]


class _Stalls:
    """An SMTP handler that takes the message's start and never answers it (a server killed
    while it waits)."""

    def __init__(self) -> None:
        self.started = threading.Event()

    async def handle_DATA(self, server: Any, session: Any, envelope: Any) -> str:
        self.started.set()
        await asyncio.sleep(3600)
        return "250 OK"


SENDER = """
import sys
from datetime import date
from pathlib import Path
from opendnc.server.config.alerts import EmailTarget
from opendnc.server.config.shop import parse_config
from opendnc.server.reports.mail import ShiftMailer
from opendnc.server.reports.shift import shift_period
from opendnc.server.store.db import make_engine, make_sessions
from tests.web.utilization_shop import CONFIG, local

url, port = sys.argv[1], int(sys.argv[2])
config = parse_config(CONFIG.replace('bind = "127.0.0.1:0"', 'name = "killed"'), base=Path("."))
target = EmailTarget(host="127.0.0.1", port=port, sender="dnc@shop.test",
                     to=("lead@shop.test",), timeout=600.0)
mailer = ShiftMailer(make_sessions(make_engine(url)), config, target)
mailer.send(shift_period(config, date(2026, 1, 5), "late"), local(23))
"""


def test_a_server_killed_mid_send_leaves_the_claim_and_nobody_sends_again(
    pg: tuple[str, sessionmaker[Session]], tmp_path: Path
) -> None:
    from aiosmtpd.controller import Controller

    url, sessions = pg
    stalls = _Stalls()
    port = free_port()
    controller = Controller(stalls, hostname="127.0.0.1", port=port)
    controller.start()
    script = tmp_path / "sender.py"
    script.write_text(textwrap.dedent(SENDER))
    root = Path(__file__).resolve().parents[2]
    env = {**os.environ, "PYTHONPATH": str(root)}
    proc = subprocess.Popen([sys.executable, str(script), url, str(port)], cwd=root, env=env)
    try:
        wait_for("the killed server's message to start", stalls.started.is_set, 60)
        assert _rows(sessions) == [("2026-01-05 late", "sending", "killed")]
        proc.kill()
        proc.wait(10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
        controller.stop()
    with smtp_server() as peer:
        survivor = ShiftMailer(sessions, _config(tmp_path, "b"), _target(peer.port))
        period = shift_period(survivor.config, date(2026, 1, 5), "late")
        assert not survivor.send(period, AFTER)
        assert peer.taken() == []
    assert _rows(sessions) == [("2026-01-05 late", "sending", "killed")]


def test_a_shift_is_due_from_its_settling_for_an_hour(tmp_path: Path) -> None:
    config = _config(tmp_path, "a")
    assert due(config, local(14)) == []  # the early shift's last samples are still coming
    (early,) = due(config, local(14, 1))
    assert early.key == "2026-01-05 early"
    assert [p.key for p in due(config, local(15))] == ["2026-01-05 early"]
    assert due(config, local(15, 1)) == []  # an hour after: a restart no longer sends it
    assert due(config, local(14) + timedelta(hours=8, seconds=31))[0].key == "2026-01-05 late"
