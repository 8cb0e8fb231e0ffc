"""The ``utilization`` component: sums the finished hours of the status samples while the
server runs (docs/server.md#status-samples)."""

from __future__ import annotations

import asyncio
import logging
from datetime import UTC, datetime

from sqlalchemy.exc import SQLAlchemyError
from sqlalchemy.orm import Session, sessionmaker

from opendnc.server.core.components import RunsTask
from opendnc.server.core.shifts import Calendar
from opendnc.server.utilization.collect import marks_of, roll
from opendnc.server.utilization.days import build_days
from opendnc.server.utilization.lost import build_lost

__all__ = ["ROLL_EVERY", "HourSummer"]

ROLL_EVERY = 600.0  # seconds between two rounds of summing finished hours
log = logging.getLogger(__name__)


class HourSummer(RunsTask):
    """A component: sums the finished hours every :data:`ROLL_EVERY` seconds while the
    server runs, so no question waits for more than the last minutes' samples, and the hours
    are summed long before their samples are pruned."""

    name = "utilization"
    needs = ("database",)

    def __init__(
        self,
        sessions: sessionmaker[Session],
        machines: list[str],
        calendar: Calendar | None = None,
    ) -> None:
        self.sessions = sessions
        self.machines = machines
        self.calendar = calendar

    async def run(self) -> None:
        """Sum, then wait, until cancelled; a database that is away is tried next round."""
        while True:
            await asyncio.sleep(ROLL_EVERY)
            try:
                await asyncio.to_thread(self.sum_now)
            except SQLAlchemyError as exc:
                log.warning("utilization: summing the finished hours failed: %s", exc)

    def sum_now(self, now: datetime | None = None) -> int:
        """Sum what finished up to ``now`` (the hours, then the local days, a few weeks of
        days per transaction until all are); how many machine-hours were written."""
        now = now or datetime.now(UTC)
        with self.sessions.begin() as session:
            written = roll(session, self.machines, now, self.calendar)
        while self.calendar is not None:
            with self.sessions.begin() as session:
                marks = marks_of(session)
                built = build_days(session, self.calendar, self.machines, marks)
                if not built + build_lost(session, self.calendar, self.machines, marks):
                    break
        return written
