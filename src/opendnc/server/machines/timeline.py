"""Each machine's recent states (connection, mode, execution), for the status timeline.

A recorder listens to the server's event bus for as long as the app runs and notes, per
machine, the moments its state changed (changes only: a status poll that finds the same state
writes nothing). With the server's database each change becomes a ``status_samples`` row,
written in batches off the event loop and pruned after ``[server] timeline_retention_days``,
so the timeline survives a restart (docs/dashboard.md#status-timeline). When the server stops
it writes a ``no_record`` sample for every machine: the time it was down shows as no record, not as
the last state stretched over the gap. Without a database the changes stay in memory (the
bookkeeping's own tests). The machine page draws the last hours as an SVG strip.

The state is the one classifier's (:func:`opendnc.server.core.state.classify`), stored by its
value; samples written before it say ``active`` for running and ``none`` for no record, and
read as such (:func:`opendnc.server.core.state.from_stored`).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
import time
from collections import deque
from dataclasses import dataclass
from datetime import datetime, timedelta
from typing import Any

from sqlalchemy import delete, select
from sqlalchemy.exc import DataError, DBAPIError, IntegrityError, SQLAlchemyError, StatementError
from sqlalchemy.orm import Session, sessionmaker

from opendnc.server.core.events import EventBus, LeaseChanged, MachineStatusChanged, Subscription
from opendnc.server.core.state import State, classify, from_stored
from opendnc.server.core.status import MachineStatus
from opendnc.server.store.health import reason
from opendnc.server.store.models import StatusSample, utcnow

__all__ = ["Sample", "Segment", "Timeline", "running"]

log = logging.getLogger(__name__)

MAX_CHANGES = 5000  # per machine in memory: a control that flips state every second fits hours
FLUSH_SECONDS = 1.0  # changes reach the database within about this
PRUNE_SECONDS = 3600.0
MAX_PENDING = 10_000  # held while the database is away; the oldest go first beyond this
HEARTBEAT = 30.0  # seconds between two notes that the server is recording (crash gaps)


@dataclass(frozen=True)
class Sample:
    """A machine's state from ``at`` on."""

    at: datetime
    state: State
    mode: str = ""
    execution: str = ""
    # for utilization (server/utilization/): a change of these is a sample of its own
    program: str = ""
    part_count: int | None = None
    alarm: str = ""

    @property
    def label(self) -> str:
        """What a person reads for it: the state, the control's execution word where it says
        more, the mode (``stopped, feed hold, automatic``)."""
        if self.state is State.NO_RECORD:
            return "no record (server stopped)"
        if self.state is State.OFFLINE:
            return "offline"
        execution = self.execution.replace("_", " ").lower()
        mode = self.mode.replace("_", " ").lower()
        said = [self.state.value]
        if execution not in ("", "unavailable", self.state.value):
            said.append(execution)
        if mode:
            said.append(mode)
        return ", ".join(said)


@dataclass(frozen=True)
class Segment:
    """One stretch of time in one state, placed on a strip ``width`` wide."""

    x: float
    width: float
    state: str  # a State's value: the strip's colour class
    label: str
    start: datetime | None = None  # the stretch's bounds within the strip (its title says them)
    end: datetime | None = None


# What a failed write raises: the database's own errors, and those the driver raises for a
# value it cannot bind (sqlite3: OverflowError for an int beyond 64 bits, UnicodeEncodeError).
_WRITE_ERRORS = (SQLAlchemyError, OverflowError, ValueError)
_INT_MIN, _INT_MAX = -(2**31), 2**31 - 1  # the part_count column's Integer


def _refused(exc: BaseException) -> bool:
    """Whether the error is about a sample's values (retrying it cannot help), not about a
    database that is away (a lost connection, a table being restored)."""
    if not isinstance(exc, SQLAlchemyError):
        return True  # raised by the driver binding a value
    if isinstance(exc, DataError | IntegrityError):
        return True
    # a StatementError that is no DBAPIError wraps an error of binding a parameter
    return isinstance(exc, StatementError) and not isinstance(exc, DBAPIError)


def _in_column(count: int | None) -> int | None:
    """A part count the column holds; one beyond it (a control's garbage) as unknown."""
    return count if count is None or _INT_MIN <= count <= _INT_MAX else None


# (state, mode, execution, program, part count, alarm text): a change of any is a sample
Key = tuple[State, str, str, str, int | None, str]


def _key(status: MachineStatus | None, online: bool) -> Key:
    state = classify(status, online=online)
    if state is State.OFFLINE or status is None:
        return state, "", "", "", None, ""
    alarm = "; ".join(str(e) for e in status.errors)[:200]
    return (
        state,
        status.mode[:64],
        status.execution[:32],
        status.program[:64],
        status.part_count,
        alarm,
    )


class Timeline:
    """State changes per machine, fed from the event bus (and the machine page's reads).

    Thread-safe: the recorder notes on the event loop, a page view in the thread pool.
    """

    def __init__(
        self, sessions: sessionmaker[Session] | None = None, *, retention_days: float = 7.0
    ) -> None:
        self.sessions = sessions
        self.retention = timedelta(days=retention_days)
        self.changes: dict[str, deque[Sample]] = {}  # without a database
        self.pending: deque[tuple[str, Sample]] = deque(maxlen=MAX_PENDING)
        self._failing = False  # the last flush failed: the outage is logged once, not per try
        self._last: dict[str, Key] = {}
        self._lock = threading.Lock()

    def note(
        self,
        name: str,
        status: MachineStatus | None,
        *,
        online: bool,
        at: datetime | None = None,
    ) -> bool:
        """Record the machine's state if it differs from the last one noted (True if so)."""
        return self._add(name, _key(status, online), at)

    def _add(self, name: str, key: Key, at: datetime | None) -> bool:
        with self._lock:
            if self._last.get(name) == key:
                return False
            self._last[name] = key
            sample = Sample(at or utcnow(), *key)
            if self.sessions is None:
                self.changes.setdefault(name, deque(maxlen=MAX_CHANGES)).append(sample)
            else:
                self.pending.append((name, sample))
            return True

    def forget(self, name: str) -> None:
        """This server no longer serves ``name`` (a cluster's lease lost): no record from
        now on, until the machine's new server notes its state; this one's stop marks
        nothing more for it."""
        if name in self._last:
            self._add(name, (State.NO_RECORD, "", "", "", None, ""), None)
        with self._lock:
            self._last.pop(name, None)

    def stopped(self, at: datetime | None = None) -> None:
        """The server stops: from now on, no record for any machine noted so far."""
        for name in list(self._last):
            self._add(name, (State.NO_RECORD, "", "", "", None, ""), at)

    def beat(self, server: str, at: datetime | None = None) -> None:
        """Note that ``server`` is recording now (one row of its own, ``@server``, moved
        forward every :data:`HEARTBEAT` seconds): after a crash, where its record ends."""
        if self.sessions is None:
            return
        key = f"@{server}"
        with self.sessions.begin() as session:
            row = session.scalars(select(StatusSample).where(StatusSample.machine == key)).first()
            if row is None:
                session.add(StatusSample(machine=key, at=at or utcnow(), state="alive"))
            else:
                row.at = at or utcnow()

    def close_gap(self, server: str, machines: list[str]) -> int:
        """At start: a server that ended without its stop (killed, power lost) left each
        machine's last state open; mark no record from its last heartbeat on, so the time it
        was down shows as a gap. How many machines got the mark."""
        if self.sessions is None:
            return 0
        with self.sessions.begin() as session:
            alive = session.scalar(
                select(StatusSample.at).where(StatusSample.machine == f"@{server}")
            )
            if alive is None:
                return 0
            marked = 0
            for name in machines:
                last = session.scalars(
                    select(StatusSample)
                    .where(StatusSample.machine == name)
                    .order_by(StatusSample.at.desc(), StatusSample.id.desc())
                    .limit(1)
                ).first()
                if last is None or from_stored(last.state, last.execution) is State.NO_RECORD:
                    continue
                no_record = State.NO_RECORD.value
                session.add(StatusSample(machine=name, at=max(alive, last.at), state=no_record))
                marked += 1
            return marked

    def flush(self) -> int:
        """Write the pending changes (one transaction); how many were written. A database
        that is away keeps them pending for the next try; a sample the database refuses (a
        value out of its column's range) is dropped with a log line, the others written."""
        if self.sessions is None:
            return 0
        with self._lock:
            batch = list(self.pending)
            self.pending.clear()
        if not batch:
            return 0
        try:
            self._write(batch)
        except _WRITE_ERRORS as exc:
            if not _refused(exc):
                self._away(batch, exc)
                return 0
            # Some sample of the batch is refused: one by one, so the others still go in and
            # the refused one is not queued again (it would fail every later flush).
            written = 0
            for i, (name, sample) in enumerate(batch):
                try:
                    self._write([(name, sample)])
                except _WRITE_ERRORS as one:
                    if not _refused(one):
                        self._away(batch[i:], one)
                        return written
                    log.warning(
                        "status timeline: a sample of %s at %s dropped, the database refuses "
                        "it: %s",
                        name,
                        sample.at.isoformat(),
                        reason(one),
                    )
                else:
                    written += 1
            self._failing = False
            return written
        self._failing = False
        return len(batch)

    def _write(self, batch: list[tuple[str, Sample]]) -> None:
        assert self.sessions is not None
        with self.sessions.begin() as session:
            session.add_all(
                StatusSample(
                    machine=name,
                    at=s.at,
                    state=s.state.value,
                    mode=s.mode[:64],
                    execution=s.execution[:32],
                    program=s.program[:64],
                    part_count=_in_column(s.part_count),
                    alarm=s.alarm[:200],
                )
                for name, s in batch
            )

    def _away(self, batch: list[tuple[str, Sample]], exc: BaseException) -> None:
        """The database did not take ``batch``: pending again, for the next flush."""
        if not self._failing:
            log.warning("status timeline: %d samples not written yet: %s", len(batch), reason(exc))
        self._failing = True
        with self._lock:
            # back in front of what came meanwhile; beyond the limit the oldest go
            self.pending = deque([*batch, *self.pending], maxlen=MAX_PENDING)

    def prune(self, now: datetime | None = None) -> int:
        """Delete the samples older than the retention; how many went."""
        if self.sessions is None:
            return 0
        cutoff = (now or utcnow()) - self.retention
        with self.sessions.begin() as session:
            result = session.execute(delete(StatusSample).where(StatusSample.at < cutoff))
            return int(getattr(result, "rowcount", 0) or 0)

    def history(self, name: str, since: datetime) -> list[Sample]:
        """``name``'s samples after ``since``, and the one in force at ``since``, in order."""
        if self.sessions is None:
            with self._lock:
                return list(self.changes.get(name, ()))
        with self.sessions() as session:
            before = session.scalars(
                select(StatusSample)
                .where(StatusSample.machine == name, StatusSample.at <= since)
                .order_by(StatusSample.at.desc(), StatusSample.id.desc())
                .limit(1)
            ).all()
            after = session.scalars(
                select(StatusSample)
                .where(StatusSample.machine == name, StatusSample.at > since)
                .order_by(StatusSample.at, StatusSample.id)
            ).all()
            out = [
                Sample(
                    r.at,
                    from_stored(r.state, r.execution),
                    r.mode,
                    r.execution,
                    r.program,
                    r.part_count,
                    r.alarm,
                )
                for r in (*before, *after)
            ]
        with self._lock:
            out += [s for n, s in self.pending if n == name]
        return out

    async def record(self, bus: EventBus) -> None:
        """Listen until cancelled; write changes within :data:`FLUSH_SECONDS`, prune hourly."""
        with bus.subscribe(maxsize=10_000) as sub:
            await self._listen(sub)

    async def _listen(self, sub: Subscription) -> None:
        flushed = pruned = time.monotonic()
        while True:
            # A get with its own deadline, not wait_for around it: a cancel must end this
            # loop whatever the get is doing (docs/server.md#events-and-states).
            event = await sub.get(FLUSH_SECONDS)
            if isinstance(event, LeaseChanged) and not event.held:
                self.forget(event.machine)
            elif isinstance(event, MachineStatusChanged) and event.served:
                # (a machine another server serves is recorded by that server)
                self.note(event.machine, event.status, online=event.online)
            now = time.monotonic()
            if self.sessions is not None and self.pending and now - flushed >= FLUSH_SECONDS:
                flushed = now
                await asyncio.to_thread(self.flush)
            if self.sessions is not None and now - pruned >= PRUNE_SECONDS:
                pruned = now
                await asyncio.to_thread(self._prune_logged)

    def _prune_logged(self) -> None:
        try:
            gone = self.prune()
        except SQLAlchemyError as exc:
            log.warning("status timeline: pruning failed: %s", exc)
            return
        if gone:
            log.info("status timeline: pruned %d samples older than %s", gone, self.retention)

    def segments(
        self, name: str, *, hours: float = 4.0, width: float = 1000.0, now: datetime | None = None
    ) -> list[Segment]:
        """The last ``hours`` of ``name`` as segments of a strip ``width`` wide."""
        now = now or utcnow()
        start = now - timedelta(hours=hours)
        span = (now - start).total_seconds()
        history = [s for s in self.history(name, start) if s.at < now]
        out: list[Segment] = []
        for i, sample in enumerate(history):
            until = history[i + 1].at if i + 1 < len(history) else now
            if until <= start:
                continue
            begin = max(sample.at, start)
            x = (begin - start).total_seconds() / span * width
            w = (until - begin).total_seconds() / span * width
            segment = Segment(
                round(x, 2),
                round(max(w, 0.5), 2),
                sample.state.value,
                sample.label,
                begin,
                until,
            )
            out.append(segment)
        return out


@contextlib.asynccontextmanager
async def running(timeline: Timeline, bus: EventBus) -> Any:
    """Run the recorder for the duration of the ``async with`` block; at its end, mark every
    machine as not recorded from then on and write what is pending."""
    if timeline.sessions is not None:
        await asyncio.to_thread(timeline._prune_logged)
    # Subscribed before the block runs: no event published in it is missed.
    with bus.subscribe(maxsize=10_000) as sub:
        task = asyncio.create_task(timeline._listen(sub), name="status-timeline")
        try:
            yield
        finally:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
            timeline.stopped()
            await asyncio.to_thread(timeline.flush)
