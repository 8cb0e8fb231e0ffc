"""Every machine's status on every server of a cluster, through the database.

Each machine is polled by one server only, the one holding its lease (:mod:`.cluster`). That
server writes what ``/api/machines`` shows for the machine into ``machine_snapshots`` a few
times a second; every server reads the rows of the machines it does not serve and publishes
them on its own bus (:class:`~opendnc.server.events.MachineStatusChanged` with
``served=False``), so the dashboard, the API, the event streams and MTConnect read the same on
every server (docs/server.md#several-servers). Only the serving server records a machine's
timeline and publishes it over MQTT.

Times are the database's: a reader asks for rows written since the last it saw, less a margin
for transactions that began before and committed after it.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Mapping
from datetime import datetime, timedelta
from typing import Any

from sqlalchemy import select, text
from sqlalchemy.dialects.postgresql import insert as pg_insert
from sqlalchemy.orm import Session, sessionmaker

from opendnc.server.components import cancel_and_wait
from opendnc.server.events import MachineStatusChanged
from opendnc.server.machine_state import Machines, MachineState
from opendnc.server.machines.base import MachineStatus
from opendnc.server.runner import database_down
from opendnc.server.store.models import MachineLease, MachineSnapshot

__all__ = ["SharedStatus", "status_from_json"]

log = logging.getLogger(__name__)

INTERVAL = 0.25  # seconds between two writes (and two reads) of the snapshots
OVERLAP = timedelta(seconds=5)  # a read looks back this far: commits land out of order


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


class SharedStatus:
    """Writes the served machines' status, reads the others' (a component, PostgreSQL only)."""

    name = "shared-status"
    needs = ("machines",)

    def __init__(
        self,
        machines: Machines,
        sessions: sessionmaker[Session],
        server: str,
        *,
        interval: float = INTERVAL,
    ) -> None:
        self.machines = machines
        self.sessions = sessions
        self.server = server
        self.interval = interval
        self._seen: dict[str, datetime] = {}  # machine -> the newest row applied
        self._cursor: datetime | None = None
        self._task: asyncio.Task[None] | None = None
        self._rounds = 0
        self.unserved: set[str] = set()  # machines no server holds a live lease on
        self.written = 0  # rows written, for the benchmark
        self.applied = 0  # rows read and published

    async def start(self) -> None:
        """Subscribe to the served machines' status and start sharing."""
        self._task = asyncio.create_task(self._run(), name="shared-status")

    async def stop(self) -> None:
        """Stop sharing."""
        task, self._task = self._task, None
        if task is not None:
            await cancel_and_wait(task)

    async def _run(self) -> None:
        pending: dict[str, dict[str, Any]] = {}
        with self.machines.bus.subscribe(maxsize=100_000) as sub:
            while True:
                loop = asyncio.get_running_loop()
                until = loop.time() + self.interval
                while (left := until - loop.time()) > 0:
                    event = await sub.get(left)
                    if isinstance(event, MachineStatusChanged) and event.served:
                        pending[event.machine] = dict(event.snapshot)
                if sub.take_overflow():
                    # events were lost: the served machines as they are now
                    for state in self.machines.machines.values():
                        if state.served:
                            pending[state.config.name] = state.as_json()
                batch, pending = pending, {}
                try:
                    rows = await asyncio.to_thread(self._exchange, batch)
                except Exception as exc:
                    if not database_down(exc):
                        log.exception("sharing the machines' status failed")
                    pending = {**batch, **pending}  # written at the next try
                    continue
                for machine, data in rows:
                    self._apply(machine, data)
                for machine in self.unserved:
                    self._orphan(machine)

    def _exchange(self, batch: dict[str, dict[str, Any]]) -> list[tuple[str, dict[str, Any]]]:
        """Write ``batch``; read the rows of other servers written since the last read."""
        with self.sessions.begin() as session:
            now = session.execute(text("SELECT now()")).scalar_one()
            if batch:
                statement = pg_insert(MachineSnapshot)
                session.execute(
                    statement.on_conflict_do_update(
                        index_elements=[MachineSnapshot.machine],
                        set_={
                            "server": statement.excluded.server,
                            "updated": statement.excluded.updated,
                            "data": statement.excluded.data,
                        },
                    ),
                    [
                        {"machine": m, "server": self.server, "updated": now, "data": data}
                        for m, data in batch.items()
                    ],
                )
                self.written += len(batch)
            self._rounds += 1
            if self._rounds % 4 == 1:  # once a second: which machines nobody serves
                live = set(
                    session.scalars(
                        select(MachineLease.machine).where(
                            MachineLease.owner != "", MachineLease.expires > now
                        )
                    )
                )
                self.unserved = set(self.machines.machines) - live
            query = select(MachineSnapshot).where(MachineSnapshot.server != self.server)
            if self._cursor is not None:
                query = query.where(MachineSnapshot.updated > self._cursor - OVERLAP)
            found = session.scalars(query).all()
            self._cursor = now
            out = []
            for row in found:
                if self._seen.get(row.machine) == row.updated:
                    continue
                if row.machine in self._seen and self._seen[row.machine] > row.updated:
                    continue
                self._seen[row.machine] = row.updated
                out.append((row.machine, dict(row.data)))
            return out

    def _orphan(self, machine: str) -> None:
        """No server holds the machine's lease (its server died, or every server it is
        pinned to is down): say so instead of showing its last status as if it were live."""
        state = self.machines.get(machine)
        if state is None or state.served or not state.online:
            return
        state.online = False
        state.last_error = "no server serves this machine now"
        self.machines.publish(state)

    def _apply(self, machine: str, data: dict[str, Any]) -> None:
        state = self.machines.get(machine)
        if state is None or state.served:
            return
        try:
            _fill(state, data)
        except (KeyError, TypeError, ValueError):
            log.warning("%s: a status row this server cannot read; left out", machine)
            return
        self.applied += 1
        self.machines.publish(state)


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
