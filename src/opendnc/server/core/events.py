"""The in-process event bus and its typed events (docs/server.md#events-and-states).

Publishers (the machine tasks, the job runner, the library watcher, the DPRNT capture, the
routes after their commit) put one of the event classes below on the bus; every consumer (the
status timeline, the dashboard's live cards, the API's server-sent events, MQTT, MTConnect)
matches on the class instead of re-reading a dict. Each event knows the JSON the API's
server-sent events and MQTT carry for it (:meth:`Event.as_json`), and its SSE name
(:attr:`Event.kind`).

A subscriber that falls behind loses its oldest events rather than slowing the machines down;
it is told so (:meth:`Subscription.take_overflow`) and sends a fresh snapshot.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections import deque
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

from opendnc.server.core.jobwords import JobKind, JobState
from opendnc.server.core.state import State, classify
from opendnc.server.core.status import MachineStatus

__all__ = [
    "DprntLinePrinted",
    "DprntStatus",
    "Event",
    "EventBus",
    "InboxChanged",
    "JobEvent",
    "JobFinished",
    "JobProgress",
    "JobQueued",
    "JobStarted",
    "LeaseChanged",
    "MachineStatusChanged",
    "NetshareChanged",
    "Overflow",
    "ProgramChanged",
    "ProgramReceived",
    "Subscription",
    "TransferProgress",
    "on_loop",
    "publish_job_queued",
    "stored_progress",
]


class Event:
    """Base of every event: its SSE name, the key a throttled stream coalesces by, its JSON."""

    kind: ClassVar[str]

    @property
    def key(self) -> str:
        """Events with equal ``(kind, key)`` supersede each other in a throttled stream."""
        raise NotImplementedError

    def as_json(self) -> dict[str, Any]:
        """What the API's server-sent events (and MQTT) carry for this event."""
        raise NotImplementedError


# -- machines ------------------------------------------------------------------------------


@dataclass(frozen=True)
class MachineStatusChanged(Event):
    """A machine's task read its status (or lost its control); SSE ``machine``.

    ``snapshot`` is the machine as ``/api/machines`` shows it, sent as it is by the API's
    stream; the typed fields are what the timeline and the outputs read.
    """

    kind: ClassVar[str] = "machine"
    machine: str
    online: bool
    status: MachineStatus | None
    last_error: str = ""  # why the link broke last (kept after a reconnect)
    snapshot: Mapping[str, Any] = field(default_factory=dict, compare=False)
    served: bool = True
    """False when another server of a cluster serves the machine and this is its status as
    that server wrote it (docs/server.md#several-servers): shown on every server's pages,
    streams and MTConnect, but recorded (timeline) and published (MQTT) by its server only."""

    @property
    def key(self) -> str:
        return self.machine

    @property
    def state(self) -> State:
        """The machine's state by the one classifier
        (:func:`opendnc.server.core.state.classify`)."""
        return classify(self.status, online=self.online)

    def as_json(self) -> dict[str, Any]:
        return dict(self.snapshot)


@dataclass(frozen=True)
class LeaseChanged(Event):
    """This server gained (``held``) or lost a machine's lease (several servers on one
    database, docs/server.md#several-servers); SSE ``lease``.

    A gain is published before the machine's task starts (its first status follows it), a
    loss once the task has stopped (no status of this server follows it): what an output
    needs to say "this server serves the machine from now on / no longer" (a Sparkplug
    DBIRTH / DDEATH). A single server (SQLite) holds every machine: it publishes a gain for
    each as it starts (epoch 0) and no loss: its stop ends them all at once, as a cluster
    server's crash does. ``epoch`` is the lease's, which grows at every change of owner.
    ``reason`` says why a loss happened (the server stops, the lease was handed over or may
    have expired), in words an output can show as the machine's message.
    """

    kind: ClassVar[str] = "lease"
    machine: str
    server: str
    held: bool
    epoch: int = 0
    reason: str = ""

    @property
    def key(self) -> str:
        return self.machine

    def as_json(self) -> dict[str, Any]:
        return {
            "machine": self.machine,
            "server": self.server,
            "held": self.held,
            "epoch": self.epoch,
        }


# -- jobs ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class JobEvent(Event):
    """Something that happened to a job; SSE ``job``. ``program`` and ``version`` name what
    it sends (None for jobs that take from the control); ``target`` is the path on the
    control or the report's name for those."""

    kind: ClassVar[str] = "job"
    event: ClassVar[str]
    job_id: int
    machine: str
    job_kind: JobKind
    program: str | None = None
    version: int | None = None

    @property
    def key(self) -> str:
        # Every start and end is news of its own; only progress coalesces (JobProgress).
        return f"{self.job_id}:{self.event}"

    @property
    def state(self) -> JobState:
        """The job's state after this event."""
        raise NotImplementedError

    def as_json(self) -> dict[str, Any]:
        return {
            "id": self.job_id,
            "machine": self.machine,
            "event": self.event,
            "state": self.state.value,
            "kind": self.job_kind.value,
            "program": self.program,
            "version": self.version,
        }


@dataclass(frozen=True)
class JobQueued(JobEvent):
    """A job entered the queue (by the API, a page, a remote request, a retry)."""

    event: ClassVar[str] = "queued"
    by: str = ""

    @property
    def state(self) -> JobState:
        return JobState.QUEUED

    def as_json(self) -> dict[str, Any]:
        return {**super().as_json(), "by": self.by}


@dataclass(frozen=True)
class JobStarted(JobEvent):
    """A machine's task claimed the job and starts it."""

    event: ClassVar[str] = "started"
    bytes_total: int | None = None

    @property
    def state(self) -> JobState:
        return JobState.RUNNING

    def as_json(self) -> dict[str, Any]:
        return {**super().as_json(), "bytes_done": 0, "bytes_total": self.bytes_total}


@dataclass(frozen=True)
class JobProgress(JobEvent):
    """Bytes of the program as stored that reached the control (see :func:`stored_progress`);
    a drip-feed adds the line it reached and the program's lines."""

    event: ClassVar[str] = "progress"
    bytes_done: int = 0
    bytes_total: int | None = None
    line: int | None = None
    lines: int | None = None

    @property
    def key(self) -> str:
        return str(self.job_id)

    @property
    def state(self) -> JobState:
        return JobState.RUNNING

    @classmethod
    def of(
        cls,
        job_id: int,
        machine: str,
        job_kind: JobKind,
        program: str | None,
        version: int | None,
        progress: TransferProgress,
    ) -> JobProgress:
        """The event of a job's ``progress`` as its executor reported it."""
        return cls(
            job_id,
            machine,
            job_kind,
            program,
            version,
            bytes_done=progress.bytes_done,
            bytes_total=progress.bytes_total,
            line=progress.line,
            lines=progress.lines,
        )

    @property
    def percent(self) -> int | None:
        """Whole percent done, None when the total is not known."""
        return percent(self.bytes_done, self.bytes_total)

    def as_json(self) -> dict[str, Any]:
        out = {
            **super().as_json(),
            "bytes_done": self.bytes_done,
            "bytes_total": self.bytes_total,
        }
        if self.line is not None:
            out.update(line=self.line, lines=self.lines)
        return out


@dataclass(frozen=True)
class JobFinished(JobEvent):
    """The job ended this run: ``outcome`` is its state now (done, failed, cancelled,
    interrupted, or queued again for a retry), ``error`` why it did not succeed."""

    event: ClassVar[str] = "finished"
    outcome: JobState = JobState.DONE
    error: str = ""

    @property
    def state(self) -> JobState:
        return self.outcome

    def as_json(self) -> dict[str, Any]:
        out = super().as_json()
        if self.error:
            out["error"] = self.error
        return out


@dataclass(frozen=True)
class TransferProgress:
    """How far a job's transfer is, as an executor reports it to the runner (which publishes
    it as a :class:`JobProgress`): bytes of the program as stored (:func:`stored_progress`),
    and a drip-feed's line reached of its lines."""

    bytes_done: int
    bytes_total: int | None = None
    line: int | None = None
    lines: int | None = None


def percent(done: int, total: int | None) -> int | None:
    """Whole percent of ``done`` in ``total`` (the one rounding the card, the queue and the
    API's readers share); None when the total is unknown."""
    if not total:
        return None
    return max(0, min(100, 100 * done // total))


def stored_progress(done: int, total: int | None, stored: int) -> tuple[int, int | None]:
    """A connector's progress in bytes of the program as stored.

    Connectors report what they count: an XModem load counts the bytes on the wire, after the
    line ends became the control's EOB (a CR LF program grows by one byte a line), so its
    total is not the program's size. Progress has one definition everywhere (the card, the
    queue table, the API, MQTT): bytes of the stored program, so a wire count is scaled to
    it, exact at the start and at the end.
    """
    if stored <= 0:
        return done, total
    if total is None or total <= 0 or total == stored:
        return min(done, stored), stored
    return min(stored, done * stored // total), stored


# -- programs, receptions, DPRNT -------------------------------------------------------------


@dataclass(frozen=True)
class ProgramChanged(Event):
    """A library program changed (a new version from the watcher or an upload, a release, a
    lock, an accept); SSE ``program``."""

    kind: ClassVar[str] = "program"
    name: str
    version: int | None = None
    source: str = "request"  # watcher or request

    @property
    def key(self) -> str:
        return self.name

    def as_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"name": self.name, "source": self.source}
        if self.version is not None:
            out["version"] = self.version
        return out


@dataclass(frozen=True)
class InboxChanged(Event):
    """A reception was accepted or discarded; SSE ``inbox``."""

    kind: ClassVar[str] = "inbox"
    received_id: str
    source: str = "request"

    @property
    def key(self) -> str:
        return self.received_id

    def as_json(self) -> dict[str, Any]:
        return {"name": self.received_id, "source": self.source}


@dataclass(frozen=True)
class _MachineMessage(Event):
    """A machine's one-line news: ``machine`` and ``message``, newest per machine."""

    machine: str
    message: str

    @property
    def key(self) -> str:
        return self.machine

    def as_json(self) -> dict[str, Any]:
        return {"machine": self.machine, "message": self.message}


@dataclass(frozen=True)
class ProgramReceived(_MachineMessage):
    """A machine sent a program by itself (a punch, a remote request, its receive folder);
    SSE ``received``."""

    kind: ClassVar[str] = "received"


@dataclass(frozen=True)
class NetshareChanged(Event):
    """The net share pushed, collected or archived a file; SSE ``netshare``."""

    kind: ClassVar[str] = "netshare"
    action: str
    machine: str  # empty for the NAS itself
    name: str
    detail: Mapping[str, Any] = field(default_factory=dict, compare=False)

    @property
    def key(self) -> str:
        return self.machine or "nas"

    def as_json(self) -> dict[str, Any]:
        return {"action": self.action, "machine": self.machine, "name": self.name, **self.detail}


@dataclass(frozen=True)
class DprntLinePrinted(Event):
    """A line a machine printed, as stored; SSE ``dprnt``."""

    kind: ClassVar[str] = "dprnt"
    line_id: int
    machine: str
    at: str  # ISO 8601, UTC
    line: str
    fields: tuple[Mapping[str, Any], ...] = ()
    complete: bool = True

    @property
    def key(self) -> str:
        return str(self.line_id)  # every line is kept, not just the newest

    def as_json(self) -> dict[str, Any]:
        return {
            "id": self.line_id,
            "machine": self.machine,
            "at": self.at,
            "line": self.line,
            "numbers": [f["value"] for f in self.fields],
            "fields": [dict(f) for f in self.fields],
            "complete": self.complete,
        }


@dataclass(frozen=True)
class DprntStatus(_MachineMessage):
    """What a DPRNT listener says about its link; SSE ``dprnt_status``."""

    kind: ClassVar[str] = "dprnt_status"


@dataclass(frozen=True)
class Overflow(Event):
    """Not published: a stream tells its reader that events were lost and a fresh snapshot
    follows; SSE ``overflow``."""

    kind: ClassVar[str] = "overflow"

    @property
    def key(self) -> str:
        return ""

    def as_json(self) -> dict[str, Any]:
        return {}


# -- the bus ---------------------------------------------------------------------------------


class Subscription:
    """A bounded queue of events for one listener.

    :meth:`get` takes a deadline itself instead of being wrapped in ``asyncio.wait_for``:
    on Python 3.11 ``wait_for`` can swallow a cancel that arrives as the inner get completes,
    and a loop around it then never ends (docs/server.md#events-and-states). Here the waiting
    task awaits a plain future, set by a new event or by the deadline's timer: there is no
    inner task whose result could win over the cancel, so a cancel always ends the wait.
    """

    def __init__(self, maxsize: int) -> None:
        self.maxsize = maxsize
        self._items: deque[Event] = deque()
        self._waiter: asyncio.Future[None] | None = None
        self.overflowed = False

    def put(self, event: Event) -> None:
        """Queue ``event``, dropping the oldest one when full."""
        if len(self._items) >= self.maxsize:
            self.overflowed = True
            self._items.popleft()
        self._items.append(event)
        waiter = self._waiter
        if waiter is not None and not waiter.done():
            waiter.set_result(None)

    async def get(self, timeout: float | None = None) -> Event | None:
        """The next event; None when ``timeout`` seconds pass without one."""
        if not self._items:
            if timeout is not None and timeout <= 0:
                return None
            loop = asyncio.get_running_loop()
            waiter: asyncio.Future[None] = loop.create_future()
            self._waiter = waiter
            timer = None
            if timeout is not None:
                timer = loop.call_later(timeout, _wake, waiter)
            try:
                await waiter
            finally:
                if timer is not None:
                    timer.cancel()
                self._waiter = None
        return self._items.popleft() if self._items else None

    async def next(self) -> Event:
        """The next event, however long it takes."""
        while True:
            event = await self.get()
            if event is not None:
                return event

    def drain(self) -> list[Event]:
        """Every event queued now, without waiting (oldest first)."""
        out = list(self._items)
        self._items.clear()
        return out

    def take_overflow(self) -> bool:
        """Whether events were dropped since the last call (and forget it)."""
        overflowed, self.overflowed = self.overflowed, False
        return overflowed


def _wake(waiter: asyncio.Future[None]) -> None:
    if not waiter.done():
        waiter.set_result(None)


class EventBus:
    """Fan-out of events to every subscriber, on the event loop's thread."""

    def __init__(self) -> None:
        self._subscribers: set[Subscription] = set()
        self._loop: asyncio.AbstractEventLoop | None = None

    def bind(self, loop: asyncio.AbstractEventLoop) -> None:
        """Remember the loop, so worker threads can publish safely."""
        self._loop = loop

    @contextlib.contextmanager
    def subscribe(self, maxsize: int = 1000) -> Iterator[Subscription]:
        """Receive events for as long as the ``with`` block lasts."""
        sub = Subscription(maxsize)
        self._subscribers.add(sub)
        try:
            yield sub
        finally:
            self._subscribers.discard(sub)

    def publish(self, event: Event) -> None:
        """Deliver ``event`` to every subscriber (callable from any thread)."""
        loop = self._loop
        if loop is not None and not on_loop(loop):
            loop.call_soon_threadsafe(self._deliver, event)
        else:
            self._deliver(event)

    def _deliver(self, event: Event) -> None:
        for sub in list(self._subscribers):
            sub.put(event)


def publish_job_queued(
    bus: EventBus,
    *,
    job_id: int,
    machine: str,
    job_kind: JobKind,
    program: str | None,
    version: int | None,
    by: str,
) -> None:
    """Publish :class:`JobQueued` for a job just committed to the queue (called after the
    commit, with plain values: a committed row's attributes may no longer be loaded)."""
    bus.publish(JobQueued(job_id, machine, job_kind, program, version, by=by))


def on_loop(loop: asyncio.AbstractEventLoop) -> bool:
    """True when called on ``loop``'s own thread (while it runs)."""
    try:
        return asyncio.get_running_loop() is loop
    except RuntimeError:
        return False
