"""The shift report by e-mail at each shift's end: an HTML message with the CSV attached,
through ``[alerts]``'s SMTP server and addresses (:func:`.alert_delivery.send_email`), one
audit row per report sent or failed."""

from __future__ import annotations

import asyncio
import logging
from datetime import UTC, datetime, timedelta
from email.message import EmailMessage
from email.utils import formatdate, make_msgid

from sqlalchemy.orm import Session, sessionmaker

from opendnc.server.alerts.delivery import DeliveryError, send_email
from opendnc.server.config.alerts import EmailTarget
from opendnc.server.config.shop import ShopConfig
from opendnc.server.core.components import RunsTask
from opendnc.server.core.shifts import Period
from opendnc.server.reports.render import mail_html, subject_of
from opendnc.server.reports.shift import ShiftReport, build
from opendnc.server.store import audit

__all__ = ["SETTLE", "ShiftMailer", "message_of", "next_end"]

SETTLE = 30.0  # seconds after a shift's end: the last samples of the shift are written
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
        """Wait for each shift's end, then send its report, until cancelled."""
        while True:
            now = datetime.now(UTC)
            period = next_end(self.config, now)
            if period is None:
                return  # no shifts
            wait = (period.end - now).total_seconds() + SETTLE
            await asyncio.sleep(max(wait, 0.0))
            await asyncio.to_thread(self.send, period)

    def send(self, period: Period, now: datetime | None = None) -> bool:
        """Build and send ``period``'s report; whether it went (audited either way)."""
        sr = build(self.sessions, self.config, period, now)
        url = ""
        if self.public_url:
            url = f"{self.public_url}/reports/shift?day={sr.day.isoformat()}&shift={period.shift}"
        message = message_of(sr, self.target, self.config.server.name, url)
        result, error = "ok", ""
        try:
            send_email(self.target, message)
        except DeliveryError as exc:
            result, error = "failed", str(exc)
            log.warning("shift report %s: %s", period.key, exc)
        with self.sessions.begin() as session:
            audit.record(
                session, "server", "report.shift", result=result, shift=period.key,
                target=self.target.describe(), error=error,
            )  # fmt: skip
        return result == "ok"
