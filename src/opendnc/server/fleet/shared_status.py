"""Every machine's status on every server of a cluster, through the database.

Each machine is polled by one server only, the one holding its lease (:mod:`.cluster`). That
server writes what ``/api/machines`` shows for the machine into ``machine_snapshots``; every
server reads the rows of the machines it does not serve and publishes them on its own bus
(:class:`~opendnc.server.core.events.MachineStatusChanged` with ``served=False``), so the
dashboard, the API, the event streams and MTConnect read the same on every server
(docs/server.md#several-servers). Only the serving server records a machine's timeline and
publishes it over MQTT.

The age a user sees on another server is the poll's age at the serving server plus the way
here, so the way is kept short and cheap:

- the writer gathers :data:`INTERVAL` of polls into one transaction; a machine whose status is
  the same as the last one written but for its time gets one array ``UPDATE`` of its poll
  time (``polled``) for all such machines, a changed one an upsert of its whole ``data``;
- the transaction ends with a notice (``status:<server>``, :mod:`.notify`) that wakes the
  other servers' readers at once (and a reader reads every :data:`FALLBACK` seconds anyway:
  notices are hints);
- a reader asks for the rows each writing server wrote since the newest it read from that
  server (no look-back: one server writes in one transaction at a time, so its ``updated``
  times commit in order), and reads ``data`` only for rows whose ``changed`` differs from
  what it shows.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
from collections.abc import Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from datetime import UTC, datetime
from typing import Any

from sqlalchemy import select, text
from sqlalchemy.orm import Session, sessionmaker

from opendnc.server.core.components import cancel_and_wait
from opendnc.server.core.events import MachineStatusChanged
from opendnc.server.core.status import MachineStatus
from opendnc.server.jobs.runner import database_down
from opendnc.server.machines.state import Machines, MachineState
from opendnc.server.store.models import MachineLease, MachineSnapshot
from opendnc.server.store.notify import Topic, notify

__all__ = ["FALLBACK", "INTERVAL", "NOTICE", "ORPHANED", "SharedStatus", "status_from_json"]

log = logging.getLogger(__name__)

INTERVAL = 0.1  # seconds of polls gathered into one write
FALLBACK = 1.0  # seconds a reader waits for a notice before it reads anyway
UNSERVED_EVERY = 1.0  # seconds between two looks at which machines nobody serves
NOTICE = Topic.STATUS  # the notice's topic; its key is the writing server
ORPHANED = "no server serves this machine now"  # a machine's last error while nobody does

_SNAPSHOTS = MachineSnapshot.__table__

# Each write is one or two statements whatever the number of machines, with arrays for
# parameters: text, because these run ten times a second and SQLAlchemy's ORM insert and
# update cost more CPU than the database does. ``now()`` is the transaction's start.

# Every machine whose status only got younger: its poll time, nothing else. A row another
# server wrote since (the machine moved and back) is left alone and written whole instead
# (the rows not returned).
_TOUCH = text(
    "UPDATE machine_snapshots AS s SET updated = now(), polled = v.polled "
    "FROM unnest(CAST(:machines AS varchar[]), CAST(:polled AS timestamptz[])) "
    "AS v(machine, polled) "
    "WHERE s.machine = v.machine AND s.server = :server "
    "RETURNING s.machine"
)
# Every machine whose status changed: the whole row.
_UPSERT = text(
    "INSERT INTO machine_snapshots (machine, server, updated, changed, polled, data) "
    "SELECT v.machine, :server, now(), now(), v.polled, CAST(v.data AS json) "
    "FROM unnest(CAST(:machines AS varchar[]), CAST(:polled AS timestamptz[]), "
    "CAST(:data AS text[])) AS v(machine, polled, data) "
    "ON CONFLICT (machine) DO UPDATE SET server = excluded.server, "
    "updated = excluded.updated, changed = excluded.changed, polled = excluded.polled, "
    "data = excluded.data"
)

# The rows of the other servers written since the newest read from each (all of a server not
# read from yet).
_NEWER = text(
    "SELECT s.machine, s.server, s.updated, s.changed, s.polled FROM machine_snapshots AS s "
    "LEFT JOIN unnest(CAST(:servers AS varchar[]), CAST(:since AS timestamptz[])) "
    "AS c(server, since) ON c.server = s.server "
    "WHERE s.server <> :me AND (c.since IS NULL OR s.updated > c.since)"
).columns(
    _SNAPSHOTS.c.machine,
    _SNAPSHOTS.c.server,
    _SNAPSHOTS.c.updated,
    _SNAPSHOTS.c.changed,
    _SNAPSHOTS.c.polled,
)


def status_from_json(data: Mapping[str, Any] | None) -> MachineStatus | None:
    """A :class:`MachineStatus` back from its :meth:`~MachineStatus.as_json`."""
    if not data:
        return None
    fields = set(MachineStatus.__dataclass_fields__)
    values = {k: v for k, v in data.items() if k in fields}
    values["at"] = datetime.fromisoformat(str(values["at"]))
    if values.get("dprnt_at"):
        values["dprnt_at"] = datetime.fromisoformat(str(values["dprnt_at"]))
    values["errors"] = tuple(values.get("errors") or ())
    values["overrides"] = dict(values.get("overrides") or {})
    return MachineStatus(**values)


@dataclass(frozen=True)
class _Row:
    """What a read found for one machine: ``data`` None when only its poll time moved."""

    machine: str
    changed: datetime | None
    polled: datetime | None
    data: Mapping[str, Any] | None


@dataclass(frozen=True)
class _Shown:
    """What a row put into a machine's state: a row that moves only the poll time applies to
    that state only while nothing else has changed it."""

    status: MachineStatus | None
    online: bool
    last_error: str
    job_id: int | None

    @classmethod
    def of(cls, state: MachineState) -> _Shown:
        return cls(state.status, state.online, state.last_error, state.job_id)

    def still(self, state: MachineState) -> bool:
        """Whether ``state`` is as this row left it (the status the very same object)."""
        return (
            state.status is self.status
            and state.online == self.online
            and state.last_error == self.last_error
            and state.job_id == self.job_id
        )


class SharedStatus:
    """Writes the served machines' status, reads the others' (a component, PostgreSQL only)."""

    name = "shared-status"
    # it shows other servers' machines to the outputs: they listen before its first status
    needs = ("machines", "database", "outputs", "timeline")

    def __init__(
        self,
        machines: Machines,
        sessions: sessionmaker[Session],
        server: str,
        *,
        interval: float = INTERVAL,
        fallback: float = FALLBACK,
    ) -> None:
        self.machines = machines
        self.sessions = sessions
        self.server = server
        self.interval = interval
        self.fallback = fallback
        self._tasks: list[asyncio.Task[None]] = []
        self._wake = asyncio.Event()
        # the writer's thread: what each machine's row holds (its status's time left out)
        self._written: dict[str, dict[str, Any]] = {}
        # the reader's thread: each writing server -> the newest ``updated`` read from it
        self._cursor: dict[str, datetime] = {}
        self._looked: datetime | None = None  # the database's time of the last lease look
        # the loop: each machine shown from a row -> (its ``changed``, the status it gave)
        self._shown: dict[str, tuple[datetime | None, _Shown]] = {}
        self._refetch: set[str] = set()  # machines whose data the next read takes whole
        self.unserved: set[str] = set()  # machines no server holds a live lease on
        self.written = 0  # rows written whole, for the benchmark and the tests
        self.touched = 0  # rows whose poll time only was written
        self.applied = 0  # rows read and published
        self.reads = 0

    async def start(self) -> None:
        """Start writing the served machines' status and reading the others'."""
        self._writer = ThreadPoolExecutor(1, thread_name_prefix="shared-status-write")
        self._reader = ThreadPoolExecutor(1, thread_name_prefix="shared-status-read")
        # subscribed here, not in the task: no status published from now on is missed
        self._sub_cm = self.machines.bus.subscribe(maxsize=100_000)
        sub = self._sub_cm.__enter__()
        self._tasks = [
            asyncio.create_task(self._writing(sub), name="shared-status-write"),
            asyncio.create_task(self._reading(), name="shared-status-read"),
        ]

    async def stop(self) -> None:
        """Stop sharing."""
        tasks, self._tasks = self._tasks, []
        await cancel_and_wait(*tasks)
        self._sub_cm.__exit__(None, None, None)
        self._writer.shutdown(wait=False)
        self._reader.shutdown(wait=False)

    def wake(self, server: str = "") -> None:
        """A notice that ``server`` wrote statuses ("" for "maybe": the listener came back):
        read now. Called on the loop."""
        if server != self.server:
            self._wake.set()

    # -- writing ----------------------------------------------------------------------------

    async def _writing(self, sub: Any) -> None:
        loop = asyncio.get_running_loop()
        pending: dict[str, Mapping[str, Any]] = {}
        while True:
            await asyncio.sleep(self.interval)
            for event in sub.drain():
                if isinstance(event, MachineStatusChanged) and event.served:
                    pending[event.machine] = event.snapshot  # a fresh dict, never changed
            if sub.take_overflow():
                # events were lost: the served machines as they are now
                for state in self.machines.machines.values():
                    if state.served:
                        pending[state.config.name] = state.as_json()
            if not pending:
                continue
            batch, pending = pending, {}
            try:
                await loop.run_in_executor(self._writer, self._write, batch)
            except Exception as exc:
                if not database_down(exc):
                    log.exception("sharing the machines' status failed")
                pending = {**batch, **pending}  # written at the next try

    def _write(self, batch: Mapping[str, Mapping[str, Any]]) -> None:
        """Write ``batch`` (machine -> snapshot) in one transaction, and say so. Writer's
        thread."""
        contents = {m: _content(snapshot) for m, snapshot in batch.items()}
        touch = [m for m, content in contents.items() if self._written.get(m) == content]
        whole = [m for m, content in contents.items() if self._written.get(m) != content]
        with self.sessions.begin() as session:
            if touch:
                params = {
                    "server": self.server,
                    "machines": touch,
                    "polled": [_polled(batch[m]) for m in touch],
                }
                done = set(session.scalars(_TOUCH, params))
                whole += [m for m in touch if m not in done]
                self.touched += len(done)
            if whole:
                params = {
                    "server": self.server,
                    "machines": whole,
                    "polled": [_polled(batch[m]) for m in whole],
                    "data": [json.dumps(batch[m]) for m in whole],
                }
                session.execute(_UPSERT, params)
            notify(session, NOTICE, self.server)
        for m in whole:
            self._written[m] = contents[m]
        self.written += len(whole)

    # -- reading ----------------------------------------------------------------------------

    async def _reading(self) -> None:
        loop = asyncio.get_running_loop()
        next_look = 0.0  # at which loop time to look at the unserved machines again
        while True:
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(self.fallback):
                    await self._wake.wait()
            self._wake.clear()
            look = loop.time() >= next_look
            refetch, self._refetch = self._refetch, set()
            try:
                rows, unserved, served = await loop.run_in_executor(
                    self._reader, self._read, refetch, look
                )
            except Exception as exc:
                if not database_down(exc):
                    log.exception("reading the machines' status failed")
                self._refetch |= refetch
                continue
            if unserved is not None:
                next_look = loop.time() + UNSERVED_EVERY
                self.unserved = unserved
            self.unserved -= served
            for row in rows:
                self._apply(row)
            for machine in self.unserved:
                self._orphan(machine)

    def _read(self, refetch: set[str], look: bool) -> tuple[list[_Row], set[str] | None, set[str]]:
        """The other servers' rows written since the last read (and ``refetch``'s whole);
        with ``look``, the machines nobody serves; the machines whose rows were written after
        the last look (their server held them then). Reader's thread."""
        t = _SNAPSHOTS.c
        cursor = {
            "me": self.server,
            "servers": list(self._cursor),
            "since": list(self._cursor.values()),
        }
        unserved = None
        with self.sessions.begin() as session:
            found = session.execute(_NEWER, cursor).all()
            need = set(refetch)
            for row in found:
                shown = self._shown.get(row.machine)
                if row.changed is None or shown is None or shown[0] != row.changed:
                    need.add(row.machine)
            whole = {}
            if need:
                whole = {
                    r.machine: r
                    for r in session.execute(
                        select(t.machine, t.changed, t.polled, t.data).where(
                            t.machine.in_(need), t.server != self.server
                        )
                    )
                }
            if look:
                now = session.execute(text("SELECT now()")).scalar_one()
                live = session.scalars(
                    select(MachineLease.machine).where(
                        MachineLease.owner != "", MachineLease.expires > now
                    )
                )
                unserved = set(self.machines.machines) - set(live)
                self._looked = now
        self.reads += 1
        for row in found:
            newest = self._cursor.get(row.server)
            if newest is None or row.updated > newest:
                self._cursor[row.server] = row.updated
        out = [_Row(r.machine, r.changed, r.polled, r.data) for r in whole.values()]
        out += [_Row(r.machine, r.changed, r.polled, None) for r in found if r.machine not in whole]
        looked = self._looked
        served = {r.machine for r in found if looked is not None and r.updated > looked}
        return out, unserved, served

    def _apply(self, row: _Row) -> None:
        state = self.machines.get(row.machine)
        if state is None or state.served:
            self._shown.pop(row.machine, None)
            return
        if row.data is None:
            # only the poll time moved: on the status this server shows from that row
            shown = self._shown.get(row.machine)
            if shown is None or not shown[1].still(state):
                # something else changed it meanwhile (this server served the machine and let
                # it go, or said nobody serves it): the row's whole data at the next read
                self._refetch.add(row.machine)
                self._wake.set()
                return
        else:
            try:
                _fill(state, row.data)
            except (KeyError, TypeError, ValueError):
                log.warning("%s: a status row this server cannot read; left out", row.machine)
                return
        if state.status is not None and row.polled is not None and row.polled > state.status.at:
            # (in UTC as the serving server wrote it, whatever the database session's zone)
            state.status = replace(state.status, at=row.polled.astimezone(UTC))
        self._shown[row.machine] = (row.changed, _Shown.of(state))
        self.applied += 1
        self.machines.publish(state)

    def _orphan(self, machine: str) -> None:
        """No server holds the machine's lease (its server died, or every server it is
        pinned to is down): say so instead of showing its last status as if it were live."""
        state = self.machines.get(machine)
        if state is None or state.served or not state.online:
            return
        state.online = False
        state.last_error = ORPHANED
        self._shown.pop(machine, None)  # its next row is read whole (online again)
        self.machines.publish(state)


def _content(snapshot: Mapping[str, Any]) -> dict[str, Any]:
    """A snapshot without its status's time: two polls that read the same compare equal."""
    status = snapshot.get("status")
    if not status:
        return dict(snapshot)
    return {**snapshot, "status": {**status, "at": None}}


def _polled(snapshot: Mapping[str, Any]) -> str | None:
    """The time of the snapshot's status (ISO 8601, as the database reads it), None without
    a status."""
    status = snapshot.get("status")
    return str(status["at"]) if status else None


def _fill(state: MachineState, data: Mapping[str, Any]) -> None:
    state.online = bool(data.get("online"))
    state.status = status_from_json(data.get("status"))
    state.last_error = str(data.get("last_error") or "")
    at = data.get("last_error_at")
    state.last_error_at = datetime.fromisoformat(str(at)) if at else None
    state.link_errors = int(data.get("link_errors") or 0)
    job = data.get("job")
    if job:
        state.job_id = int(job["id"])
        total = job.get("bytes_total")
        state.job_progress = (int(job.get("bytes_done") or 0), int(total) if total else None)
    else:
        state.job_id = None
        state.job_progress = (0, None)
