"""The shift report by e-mail at each shift's end: an HTML message with the CSV attached,
through ``[alerts]``'s SMTP server and addresses (:func:`.alert_delivery.send_email`), one
audit row per report sent or failed.

A cluster's duty done once: every server runs the mailer, and each report is claimed in
``shift_reports`` (:class:`~opendnc.server.store.models.ShiftReportSent`) before it is built
and sent; the server whose insert goes through sends it, the others (and this one after a
restart) find the row and do not. A server started within :data:`CATCH_UP` of a shift's end
sends that report if nobody has. A claim left at ``sending`` (a server killed mid-send) is
never sent again: the row says so, and a second copy is worse than a missing one."""

from __future__ import annotations

import asyncio
import logging
from datetime import UTC, datetime, timedelta
from email.message import EmailMessage
from email.utils import formatdate, make_msgid

from sqlalchemy.orm import Session, sessionmaker

from opendnc.errors import DncError
from opendnc.server.alerts.delivery import send_email
from opendnc.server.config.alerts import EmailTarget
from opendnc.server.config.shop import ShopConfig
from opendnc.server.core.components import RunsTask
from opendnc.server.core.shifts import Period
from opendnc.server.reports.render import mail_html, subject_of
from opendnc.server.reports.shift import ShiftReport, build
from opendnc.server.store import audit
from opendnc.server.store.claims import claim_once
from opendnc.server.store.models import ShiftReportSent, utcnow

__all__ = ["CATCH_UP", "SETTLE", "ShiftMailer", "due", "message_of", "next_end"]

SETTLE = 30.0  # seconds after a shift's end: the last samples of the shift are written
CATCH_UP = timedelta(hours=1)  # a shift that ended this recently is still mailed at start
log = logging.getLogger(__name__)


def message_of(
    sr: ShiftReport, target: EmailTarget, server: str = "", url: str = ""
) -> EmailMessage:
    """The e-mail of one shift report: the HTML report (a plain text part for readers
    without HTML) and the CSV attached."""
    message = EmailMessage()
    message["Subject"] = f"[opendnc] {subject_of(sr, server)}"
    message["From"] = target.sender
    message["To"] = ", ".join(target.to)
    message["Date"] = formatdate(localtime=False)
    message["Message-ID"] = make_msgid("opendnc", domain=target.sender.rsplit("@", 1)[1])
    lines = [subject_of(sr, server), ""]
    for m in sr.report.machines:
        floor = sr.report.floor.of(m.machine) if sr.report.floor else None
        oee = floor.totals.oee if floor is not None else None
        util = m.totals.utilization
        lines.append(
            f"{m.machine}: utilization {'-' if util is None else f'{util:.1f} %'}, "
            f"OEE {'-' if oee is None else f'{100 * oee:.1f} %'}"
        )
    message.set_content("\n".join(lines) + "\n")
    message.add_alternative(mail_html(sr, server, url), subtype="html")
    name = f"shift-{sr.day:%Y%m%d}-{sr.period.shift}.csv"
    message.add_attachment(sr.csv.encode(), maintype="text", subtype="csv", filename=name)
    return message


def next_end(config: ShopConfig, now: datetime) -> Period | None:
    """The next shift to end after ``now`` (within a week)."""
    ahead = config.calendar.shift_periods(now - timedelta(days=1), now + timedelta(days=8))
    coming = [p for p in ahead if p.end > now]
    return min(coming, key=lambda p: p.end) if coming else None


def due(config: ShopConfig, now: datetime) -> list[Period]:
    """The shifts whose report is due at ``now``: ended (and settled) within :data:`CATCH_UP`."""
    settled = now - timedelta(seconds=SETTLE)
    ended = config.calendar.shift_periods(now - CATCH_UP - timedelta(days=1), settled)
    return [p for p in ended if settled - CATCH_UP < p.end <= settled]


class ShiftMailer(RunsTask):
    """A component: at each shift's end (and :data:`SETTLE` seconds), mails its report."""

    name = "shift-reports"
    needs = ("database",)

    def __init__(
        self,
        sessions: sessionmaker[Session],
        config: ShopConfig,
        target: EmailTarget,
        public_url: str = "",
    ) -> None:
        self.sessions = sessions
        self.config = config
        self.target = target
        self.public_url = public_url

    async def run(self) -> None:
        """Send the reports due (a shift that ended while this server was down, within
        :data:`CATCH_UP`), then wait for each shift's end and send its report, until
        cancelled. Each is claimed first: a report another server sent is not sent here."""
        while True:
            now = datetime.now(UTC)
            for ended in due(self.config, now):
                try:
                    await asyncio.to_thread(self.send, ended)
                except Exception as exc:  # the database away: the next shift's end tries again
                    log.warning("shift report %s: %s", ended.key, type(exc).__name__)
            period = next_end(self.config, now)
            if period is None:
                return  # no shifts
            wait = (period.end - now).total_seconds() + SETTLE
            await asyncio.sleep(max(wait, 0.5))

    def claim(self, period: Period) -> bool:
        """Claim ``period``'s report for this server; False if it is claimed already."""
        row = ShiftReportSent(shift=period.key, server=self.config.server.name)
        return claim_once(self.sessions, row)

    def send(self, period: Period, now: datetime | None = None) -> bool:
        """Claim, build and send ``period``'s report; whether it went from here (audited
        either way). A report claimed already (by another server, or before a restart) is
        not sent."""
        if not self.claim(period):
            log.info("shift report %s: claimed already, not sent here", period.key)
            return False
        result, error = "ok", ""
        try:
            sr = build(self.sessions, self.config, period, now)
            url = ""
            if self.public_url:
                url = (
                    f"{self.public_url}/reports/shift?day={sr.day.isoformat()}&shift={period.shift}"
                )
            send_email(self.target, message_of(sr, self.target, self.config.server.name, url))
        except DncError as exc:  # a DeliveryError, or a shift the calendar does not hold
            result, error = "failed", str(exc)
            log.warning("shift report %s: %s", period.key, exc)
        with self.sessions.begin() as session:
            row = session.get(ShiftReportSent, period.key)
            if row is not None:
                row.state, row.finished, row.error = (
                    "sent" if result == "ok" else "failed",
                    utcnow(),
                    error,
                )
            audit.record(
                session, "server", "report.shift", result=result, shift=period.key,
                target=self.target.describe(), error=error,
            )  # fmt: skip
        return result == "ok"
