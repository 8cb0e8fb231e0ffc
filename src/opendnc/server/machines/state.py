"""What the server knows about each machine right now, and the way to wake its task.

:class:`Machines` is the registry the routes read (``Annotated[Machines, Depends(...)]``): each
machine's :class:`MachineState`, the event bus its changes go out on, the shop's configuration,
and :meth:`Machines.wake`, which tells a machine's task that a job may be waiting. It runs no
task itself; :mod:`opendnc.server.fleet.tasks` does.
"""

from __future__ import annotations

import asyncio
from dataclasses import dataclass, field, replace
from datetime import UTC, datetime
from typing import Any

from opendnc.server.config.shop import MachineConfig, ShopConfig
from opendnc.server.core.events import EventBus, MachineStatusChanged, on_loop
from opendnc.server.core.jobwords import JobKind
from opendnc.server.core.state import State, classify
from opendnc.server.core.status import MachineStatus
from opendnc.server.kinds.files import Errands

__all__ = ["MachineState", "Machines"]


@dataclass
class MachineState:
    """What the server knows about one machine right now."""

    config: MachineConfig
    online: bool = False
    status: MachineStatus | None = None
    last_error: str = ""  # kept after a reconnect: the last thing that went wrong
    last_error_at: datetime | None = None
    link_errors: int = 0  # how often the link broke since the server started
    job_id: int | None = None
    job_progress: tuple[int, int | None] = (0, None)
    job_started: datetime | None = None  # when the running job started (its rate, time left)
    job_line: tuple[int, int] | None = None  # a drip-feed's line reached, of its lines
    # when this server first saw the running job's bytes move, and how many there were: its
    # rate is measured from there (the wait for the control before the first byte is no
    # part of it: a 9 s load once said "about 5 min 13 s left" after its slow start)
    job_flowing: tuple[datetime, int] | None = None
    job_kind: JobKind | None = None  # the running job's kind
    job_program: str = ""  # the program (or path) it moves
    dprnt: tuple[str, datetime] | None = None  # the last DPRNT line and when it came
    wake: asyncio.Event = field(default_factory=asyncio.Event)
    # the classifier's state as last published, and since when (the card's "alarm since 14:02")
    seen_state: State | None = None
    state_since: datetime | None = None
    errands: Errands = field(default_factory=Errands)  # file browser reads on the connector
    served: bool = True  # False while another server of a cluster serves it (its status read)
    # A drip-feed a take-over ended here: (job id, the server that fed it, until when on the
    # monotonic clock its exact position is waited for, silently: no poll, no listening)
    awaiting_position: tuple[int, str, float] | None = None
    # The rest of a drip-feed may be owed to this control (a fenced feed's continuation is
    # queued here, or its position is still being written): it may wait in DNC mode, so its
    # task runs the queue and says nothing else to it until the continuation has started.
    # A hint kept in memory; the database says whether a continuation is still queued.
    feed_owed: bool = False

    def set_status(self, status: MachineStatus) -> None:
        """Take a new status, carrying the last DPRNT line over (a poll does not read it)."""
        if self.dprnt is not None:
            status = replace(status, dprnt=self.dprnt[0], dprnt_at=self.dprnt[1])
        self.status = status

    def start_job(
        self, job_id: int, total: int | None, kind: JobKind | None = None, program: str = ""
    ) -> None:
        """A job starts on this machine: its progress, start time and line start anew."""
        self.job_id, self.job_progress = job_id, (0, total)
        self.job_started, self.job_line = datetime.now(UTC), None
        self.job_kind, self.job_program = kind, program
        self.job_flowing = None

    def reading(self) -> MachineStatus | None:
        """The status the one classifier reads: the control's last word, unless what the
        server itself is doing to the machine says more. A drip-feed runs the program (the
        control executes what it is fed: running, whatever was polled before it); a load
        into a control that tells nothing (a serial Haas without MDC) has it waiting on the
        transfer, reachable and not cutting (ready). No status is polled while a job runs,
        so without this a serial Haas would read "unknown" through a whole drip-feed."""
        status = self.status
        if self.job_id is None or not self.online:
            return status
        base = status or MachineStatus(at=datetime.now(UTC), available=True)
        if self.job_kind is JobKind.DRIPFEED:
            return replace(
                base,
                execution="ACTIVE",
                program=self.job_program or base.program,
                errors=(),
                message=f"drip-feed of {self.job_program} from the server",
            )
        silent = base.execution in ("", "UNAVAILABLE") and not base.errors
        if silent and self.job_kind in (JobKind.SEND, JobKind.REPORT):
            return replace(base, execution="WAIT", message=f"loading {self.job_program}")
        return status

    def event(self) -> MachineStatusChanged:
        """The machine as it is now, as an event (published on every status read)."""
        reading = self.reading()
        state = classify(reading, online=self.online)
        if state is not self.seen_state:
            self.seen_state, self.state_since = state, datetime.now(UTC)
        name, json = self.config.name, self.as_json()
        return MachineStatusChanged(
            name, self.online, reading, self.last_error, json, served=self.served
        )

    def as_json(self) -> dict[str, Any]:
        """A JSON-ready summary for the API."""
        reading = self.reading()
        return {
            "name": self.config.name,
            "kind": self.config.kind,
            "description": self.config.description,
            "released_only": self.config.released_only,
            "online": self.online,
            # the one classifier's word: running, ready, stopped, alarm, offline, unknown
            "state": classify(reading, online=self.online).value,
            "status": reading.as_json() if reading else None,
            "last_error": self.last_error,
            "last_error_at": self.last_error_at.isoformat() if self.last_error_at else None,
            "link_errors": self.link_errors,
            # since when the machine is in this state, as far as this server saw it
            "state_since": self.state_since.isoformat() if self.state_since else None,
            "job": None if self.job_id is None else self._job_json(),
        }

    def flowing(self) -> tuple[datetime, int] | None:
        """When this server first saw the running job's bytes move, and how many there were
        (noted the first time it is asked after they moved): the job's rate starts there."""
        done = self.job_progress[0]
        if self.job_id is not None and self.job_flowing is None and done > 0:
            self.job_flowing = (datetime.now(UTC), done)
        return self.job_flowing

    def _job_json(self) -> dict[str, Any]:
        done, total = self.job_progress
        job: dict[str, Any] = {"id": self.job_id, "bytes_done": done, "bytes_total": total}
        job["started"] = self.job_started.isoformat() if self.job_started else None
        flowing = self.flowing()
        if flowing is not None:
            job["flowing"] = flowing[0].isoformat()
            job["flowing_bytes"] = flowing[1]
        if self.job_line is not None:
            job["line"], job["lines"] = self.job_line
        return job


class Machines:
    """Every configured machine's live state (a component: it binds to the running loop)."""

    name = "machines"
    needs: tuple[str, ...] = ()

    def __init__(self, config: ShopConfig, bus: EventBus) -> None:
        self.config = config
        self.bus = bus
        self.machines = {m.name: MachineState(m) for m in config.machines}
        self._loop: asyncio.AbstractEventLoop | None = None

    async def start(self) -> None:
        """Bind the registry and the bus to the running loop (threads publish through it)."""
        self._loop = asyncio.get_running_loop()
        self.bus.bind(self._loop)

    async def stop(self) -> None:
        """Nothing to release."""

    def get(self, name: str) -> MachineState | None:
        """The state of ``name``, or None."""
        return self.machines.get(name)

    def call_on_loop(self, function: Any, *args: Any) -> bool:
        """Run ``function(*args)`` on the server's loop when called from another thread;
        False when already on it (the caller runs it itself)."""
        loop = self._loop
        if loop is not None and not on_loop(loop):
            loop.call_soon_threadsafe(function, *args)
            return True
        return False

    def wake(self, machine: str) -> None:
        """Tell ``machine``'s task that a job may be waiting (callable from any thread)."""
        state = self.machines.get(machine)
        if state is None:
            return
        # The API's plain routes run in worker threads. An asyncio.Event set from there
        # schedules its waiter without waking the loop's selector (and asyncio's debug mode
        # refuses it outright), so the set goes through the loop.
        if not self.call_on_loop(state.wake.set):
            state.wake.set()

    def publish(self, state: MachineState) -> None:
        """Send ``state`` to the event bus (the cards, the outputs, the timeline)."""
        self.bus.publish(state.event())

    def note_status(self, machine: str, status: MachineStatus) -> None:
        """Take a status a connector tells by itself (from any thread): a control that reports
        nothing, whose state is what the server does with it, changes during a job, when no
        poll runs (a tape control drip-feeding is running)."""
        if self.call_on_loop(self.note_status, machine, status):
            return
        state = self.machines.get(machine)
        if state is None or not state.online:
            return
        state.set_status(status)
        self.publish(state)

    def note_dprnt(self, machine: str, text: str, at: datetime) -> None:
        """Put a line ``machine`` printed with DPRNT into its status (from any thread: the
        capture runs in listener threads and in the serial connector's worker)."""
        if self.call_on_loop(self.note_dprnt, machine, text, at):
            return
        state = self.machines.get(machine)
        if state is None:
            return
        state.dprnt = (text, at)
        if state.status is not None:
            state.set_status(state.status)
        self.publish(state)
