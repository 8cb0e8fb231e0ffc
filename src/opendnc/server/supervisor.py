"""One supervised asyncio task per machine: connect, poll status, run the machine's jobs.

A task that loses its control closes the link, waits with exponential backoff (0.5 s up to
30 s) and connects again; an error in one machine's task never reaches another's. A machine
claims jobs only when woken: by the API when it queues one in this process, and by one shared
sweep that asks the database which machines have due jobs (queued by another server sharing
the database, or retries whose backoff has expired). One query per sweep, however many
machines, keeps a large shop's database quiet.

Database work runs in worker threads (``asyncio.to_thread``): SQLAlchemy sessions are
blocking, and a slow database must not stall the status polls of every machine.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from datetime import datetime, timedelta
from typing import Any

from sqlalchemy import func, select
from sqlalchemy.orm import Session, sessionmaker

from opendnc.errors import (
    ControlRefused,
    DncError,
    InputError,
    RemoteProtocolError,
    TransferError,
    TransportError,
)
from opendnc.server import audit, inbox, jobs, library, requests
from opendnc.server.autoreceive import FolderWatch, size_problem
from opendnc.server.config import MachineConfig, ShopConfig
from opendnc.server.errors import NotFound
from opendnc.server.events import (
    EventBus,
    JobFinished,
    JobProgress,
    JobStarted,
    MachineStatusChanged,
    ProgramReceived,
    on_loop,
    publish_job_queued,
    stored_progress,
)
from opendnc.server.machine_files import RemoteFile
from opendnc.server.machines import Connector, MachineStatus, Reception, connector_for
from opendnc.server.machines.base import FolderSource
from opendnc.server.state import classify
from opendnc.server.store.db import read_only
from opendnc.server.store.models import DprntLine, JobKind, utcnow

__all__ = ["ConnectorFactory", "MachineState", "Supervisor"]

PROGRESS_EVERY = 0.1  # seconds between two progress events of one transfer

log = logging.getLogger(__name__)

ConnectorFactory = Callable[[MachineConfig], Connector]


class DripFeedBroken(DncError):
    """A drip-feed stopped; ``line`` is the program line it had reached, ``nbytes`` the
    program bytes it had fed to get there."""

    def __init__(self, reason: str, line: int, nbytes: int = 0) -> None:
        super().__init__(reason)
        self.line = line
        self.nbytes = nbytes


@dataclass(frozen=True)
class Claimed:
    """A job taken from the queue, with what running it needs."""

    job_id: int
    kind: JobKind
    name: str  # program name, or the path on the control
    data: bytes  # what to send (empty for jobs that take from the control)
    params: dict[str, Any]
    version: int | None = None  # the program version it sends


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
    dprnt: tuple[str, datetime] | None = None  # the last DPRNT line and when it came
    wake: asyncio.Event = field(default_factory=asyncio.Event)

    def set_status(self, status: MachineStatus) -> None:
        """Take a new status, carrying the last DPRNT line over (a poll does not read it)."""
        if self.dprnt is not None:
            status = replace(status, dprnt=self.dprnt[0], dprnt_at=self.dprnt[1])
        self.status = status

    def event(self) -> MachineStatusChanged:
        """The machine as it is now, as an event (published on every status read)."""
        name, json = self.config.name, self.as_json()
        return MachineStatusChanged(name, self.online, self.status, self.last_error, json)

    def as_json(self) -> dict[str, Any]:
        """A JSON-ready summary for the API."""
        done, total = self.job_progress
        return {
            "name": self.config.name,
            "kind": self.config.kind.value,
            "description": self.config.description,
            "released_only": self.config.released_only,
            "online": self.online,
            # the one classifier's word: running, ready, stopped, alarm, offline, unknown
            "state": classify(self.status, online=self.online).value,
            "status": self.status.as_json() if self.status else None,
            "last_error": self.last_error,
            "last_error_at": self.last_error_at.isoformat() if self.last_error_at else None,
            "link_errors": self.link_errors,
            "job": None
            if self.job_id is None
            else {"id": self.job_id, "bytes_done": done, "bytes_total": total},
        }


class Supervisor:
    """Runs every configured machine; ``start()`` and ``stop()`` from the app's lifespan."""

    def __init__(
        self,
        config: ShopConfig,
        sessions: sessionmaker[Session],
        bus: EventBus,
        *,
        connector_factory: ConnectorFactory = connector_for,
        sweep_interval: float = 5.0,
        retry_backoff: float = 2.0,
    ) -> None:
        self.config = config
        self.sessions = sessions
        self._reads = read_only(sessions)  # the sweep's query need not wait for the write lock
        self.bus = bus
        self.connector_factory = connector_factory
        self.sweep_interval = sweep_interval
        self.retry_backoff = retry_backoff
        self.worker = config.server.name
        self.machines = {m.name: MachineState(m) for m in config.machines}
        self._tasks: list[asyncio.Task[None]] = []
        self._cancels: set[int] = set()
        self._watches = {m.name: FolderWatch(m) for m in config.machines if m.receive_folder}
        self._loop: asyncio.AbstractEventLoop | None = None

    async def start(self) -> None:
        """Recover jobs left running by a previous run, then start one task per machine."""
        self._loop = asyncio.get_running_loop()
        self.bus.bind(self._loop)

        def prepare() -> tuple[list[int], dict[str, tuple[str, datetime]]]:
            with self.sessions.begin() as session:
                jobs.sync_machines(session, self.config.machines)
                recovered = [job.id for job in jobs.recover(session, self.worker)]
                return recovered, _last_dprnt_lines(session)

        recovered, printed = await asyncio.to_thread(prepare)
        for job_id in recovered:
            log.warning("job %d was running when the server stopped: interrupted", job_id)
        for name, line in printed.items():
            if name in self.machines:  # the status keeps showing it after a restart
                self.machines[name].dprnt = line
        for state in self.machines.values():
            self._tasks.append(asyncio.create_task(self._supervise(state), name=state.config.name))
            state.wake.set()  # a first look at the queue
        self._tasks.append(asyncio.create_task(self._sweep(), name="job-sweep"))

    async def _sweep(self) -> None:
        while True:
            await asyncio.sleep(self.sweep_interval)
            try:
                due = await asyncio.to_thread(self._due_machines)
            except Exception:
                log.exception("job sweep failed")
                continue
            for name in due:
                self.wake(name)

    def _due_machines(self) -> list[str]:
        with self._reads() as session:
            return jobs.machines_with_due_jobs(session)

    async def stop(self) -> None:
        """Cancel every machine task and wait for them to close their links."""
        for task in self._tasks:
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        self._tasks.clear()

    def wake(self, machine: str) -> None:
        """Tell ``machine``'s task that a job may be waiting (callable from any thread)."""
        state = self.machines.get(machine)
        if state is None:
            return
        loop = self._loop
        # The API's plain routes run in worker threads. An asyncio.Event set from there
        # schedules its waiter without waking the loop's selector (and asyncio's debug mode
        # refuses it outright), so the set goes through the loop.
        if loop is not None and not on_loop(loop):
            loop.call_soon_threadsafe(state.wake.set)
        else:
            state.wake.set()

    def note_dprnt(self, machine: str, text: str, at: datetime) -> None:
        """Put a line ``machine`` printed with DPRNT into its status (from any thread: the
        capture runs in listener threads and in the serial connector's worker)."""
        loop = self._loop
        if loop is not None and not on_loop(loop):
            loop.call_soon_threadsafe(self.note_dprnt, machine, text, at)
            return
        state = self.machines.get(machine)
        if state is None:
            return
        state.dprnt = (text, at)
        if state.status is not None:
            state.set_status(state.status)
        self._publish(state)

    def _publish(self, state: MachineState) -> None:
        self.bus.publish(state.event())

    async def _supervise(self, state: MachineState) -> None:
        connector = self.connector_factory(state.config)
        backoff = 0.5
        while True:
            try:
                await connector.connect()
                state.online = True
                backoff = 0.5
                await self._serve(state, connector)
            except asyncio.CancelledError:
                await connector.close()
                raise
            except Exception as exc:
                if not isinstance(exc, DncError):
                    log.exception("%s: unexpected error", state.config.name)
                state.online = False
                state.last_error = str(exc) or type(exc).__name__
                state.last_error_at = utcnow()
                state.link_errors += 1
                state.set_status(
                    MachineStatus(at=utcnow(), available=False, message=state.last_error)
                )
                self._publish(state)
                await connector.close()
                await asyncio.sleep(backoff)
                backoff = min(backoff * 2, 30.0)

    async def _serve(self, state: MachineState, connector: Connector) -> None:
        watch = self._watches.get(state.config.name)
        polls = 0
        while True:
            if state.wake.is_set():
                state.wake.clear()
                while await self._run_next(state, connector):
                    pass
            state.set_status(await connector.status())
            self._publish(state)
            if watch is not None and isinstance(connector, FolderSource):
                # Between jobs on the machine's own session: a listing never meets a transfer.
                if polls % state.config.receive_every == 0:
                    await self._autoreceive(state, connector, watch)
                polls += 1
            if connector.listens:
                # Waiting for a punch or a remote request is what a serial port does between
                # jobs; a queued job waits at most one listening window.
                reception = await connector.listen(state.config.poll_interval)
                if reception is not None:
                    await self._received(state, reception)
            else:
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(state.wake.wait(), state.config.poll_interval)

    async def _run_next(self, state: MachineState, connector: Connector) -> bool:
        name = state.config.name

        def claim() -> Claimed | None:
            with self.sessions.begin() as session:
                job = jobs.claim(session, name, self.worker)
                if job is None:
                    return None
                params = dict(job.params)
                if job.kind is JobKind.REPORT:
                    report = str(params.get("report", "")).encode("latin-1")
                    return Claimed(job.id, job.kind, str(params.get("name")), report, params)
                if job.kind in (JobKind.SEND, JobKind.DRIPFEED):
                    if job.version is None:
                        jobs.fail(session, job.id, "the job names no program", retryable=False)
                        return None
                    data = library.content(session, job.version)
                    program = job.version.program.name
                    return Claimed(job.id, job.kind, program, data, params, job.version.number)
                return Claimed(job.id, job.kind, str(params.get("path", "")), b"", params)

        claimed = await asyncio.to_thread(claim)
        if claimed is None:
            return False
        job_id = claimed.job_id
        state.job_id, state.job_progress = job_id, (0, len(claimed.data) or None)
        self.bus.publish(
            JobStarted(*self._job(claimed, name), bytes_total=len(claimed.data) or None)
        )
        try:
            outcome = await self._execute(state, connector, claimed)
        except asyncio.CancelledError:
            # Stopping the server mid-transfer: the next start marks the job interrupted.
            raise
        except Exception as exc:
            reason = str(exc) or type(exc).__name__
            # A broken link or a garbled transfer may go well next time; a refusal will not.
            retryable = isinstance(exc, TransportError | TransferError | RemoteProtocolError)
            line = exc.line if isinstance(exc, DripFeedBroken) else None
            nbytes = exc.nbytes if isinstance(exc, DripFeedBroken) else None
            if line is not None:
                reason = f"{reason} (stopped at line {line}; restart from there)"
            job = await asyncio.to_thread(self._fail, job_id, reason, retryable, line, nbytes)
            self.bus.publish(JobFinished(*self._job(claimed, name), outcome=job, error=reason))
            state.job_id = None
            cause = exc.__cause__ if isinstance(exc, DripFeedBroken) else exc
            if isinstance(cause, TransportError):
                raise exc from cause  # reconnect before the next job
            return True
        await asyncio.to_thread(self._finish, job_id, outcome)
        self.bus.publish(JobFinished(*self._job(claimed, name), outcome="done"))
        state.job_id = None
        return True

    async def _execute(
        self, state: MachineState, connector: Connector, job: Claimed
    ) -> dict[str, Any]:
        """Run one claimed job; returns what its audit row records."""
        if job.kind in (JobKind.SEND, JobKind.REPORT):
            verified = await self._send(state, connector, job)
            return {"nbytes": len(job.data), "verified": verified}
        if job.kind is JobKind.DRIPFEED:
            return await self._dripfeed(state, connector, job)
        if job.kind is JobKind.RECEIVE:
            data = await connector.fetch(job.name)
            folder = self.config.library.inbox

            def keep() -> int:
                with self.sessions.begin() as session:
                    return inbox.store(session, state.config.name, data, folder=folder).id

            received_id = await asyncio.to_thread(keep)
            return {"nbytes": len(data), "path": job.name, "received_id": received_id}
        if job.kind is JobKind.DELETE:
            await connector.delete(job.name)
            return {"path": job.name}
        if job.kind is JobKind.BACKUP:
            root = self.config.library.backups or self.config.library.archive / "backups"
            counts = await connector.backup(job.name, root / state.config.name)
            return {"path": job.name, **counts}
        raise InputError(f"{job.kind.value} jobs are not run by this server version yet")

    async def _dripfeed(
        self, state: MachineState, connector: Connector, job: Claimed
    ) -> dict[str, Any]:
        from_line = int(job.params.get("from_line", 1))
        reached = [from_line]
        fed = [0]
        machine = state.config.name

        def progress(line: int, lines: int, nbytes: int, total: int) -> None:
            # Called from the feed's thread for every chunk: only a new line is news.
            fed[0] = nbytes
            if line != reached[0]:
                reached[0] = line
                # Progress is in bytes like every job's (the card's share and sizes); the line
                # travels beside it for the restart prompt.
                state.job_progress = (nbytes, total or None)
                self.bus.publish(
                    JobProgress(
                        *self._job(job, machine),
                        bytes_done=nbytes,
                        bytes_total=total or None,
                        line=line,
                        lines=lines,
                    )
                )
            if job.job_id in self._cancels:
                raise TransferError(f"cancelled at line {line}")

        try:
            counts = await connector.dripfeed(job.name, job.data, from_line, progress)
        except Exception as exc:
            raise DripFeedBroken(str(exc) or type(exc).__name__, reached[0], fed[0]) from exc
        finally:
            self._cancels.discard(job.job_id)
        # Progress and the job's bytes are bytes of the stored program (from the start line),
        # as for every job; what went over the wire (EOB, leader, restart preamble) is kept
        # beside them in the audit row.
        wire = counts.get("nbytes")
        return {**counts, "nbytes": fed[0] or wire, "wire_bytes": wire, "from_line": from_line}

    def request_cancel(self, job_id: int) -> None:
        """Stop a running drip-feed of this process at its next chunk."""
        self._cancels.add(job_id)

    async def _received(self, state: MachineState, reception: Reception) -> None:
        """File a program the control sent: into the inbox, or answer it as a request."""
        settings = self.config.requests
        machine = state.config
        folder = self.config.library.inbox
        queued: list[dict[str, Any]] = []  # the requested programs' jobs, announced once committed

        def handle() -> tuple[str, float | None]:
            with self.sessions.begin() as session:
                if reception.failed:
                    row = inbox.store(
                        session,
                        machine.name,
                        reception.data,
                        folder=folder,
                        failed=reception.failed,
                    )
                    return f"reception failed: {row.reason}", None
                names = requests.find_request(reception.data, settings)
                if names is None:
                    row = inbox.store(session, machine.name, reception.data, folder=folder)
                    if settings.reports == "all":
                        self._report(session, machine, "RECEIVED", [f"{row.name} IN INBOX"])
                    return f"received {row.name} into the inbox", None
                return self._answer_request(session, machine, names, queued), settings.delay

        message, delay = await asyncio.to_thread(handle)
        state.last_error = "" if not reception.failed else message
        self.bus.publish(ProgramReceived(machine.name, message))
        for job in queued:
            publish_job_queued(self.bus, **job)
        if delay is not None:
            # Wake the machine when the answer falls due (the request delay).
            asyncio.get_running_loop().call_later(delay + 0.05, state.wake.set)
            state.wake.set()

    async def _autoreceive(
        self, state: MachineState, connector: FolderSource, watch: FolderWatch
    ) -> None:
        """One look at the machine's receive folder (:mod:`opendnc.server.autoreceive`)."""
        if not watch.loaded:
            await asyncio.to_thread(self._load_watch, watch)
        try:
            listing = await connector.list_files(watch.folder)
        except ControlRefused as exc:
            # No such folder (yet) on the control: the status polls go on regardless.
            state.last_error = f"receive folder {watch.folder}: {exc}"
            return
        for entry in watch.due(listing):
            try:
                data = await connector.fetch(entry.path)
            except ControlRefused as exc:
                log.info("%s: %s not read: %s", state.config.name, entry.path, exc)
                continue  # gone or locked since the listing; the next listing tells
            failed = size_problem(entry, data, entry)
            if failed is not None:
                # A size that disagrees: a second listing tells a file still being written
                # from a read that went wrong.
                again = {e.path.upper(): e for e in await connector.list_files(watch.folder)}
                failed = size_problem(entry, data, again.get(entry.path.upper()))
            if failed == "":
                continue  # it changed while we read it
            if failed is None and watch.known(entry, data):
                watch.mark(entry, data)  # touched, not changed
                continue
            await self._file_found(state, connector, watch, entry, data, failed or "")

    def _load_watch(self, watch: FolderWatch) -> None:
        with self.sessions() as session:
            watch.load(session)

    async def _file_found(
        self,
        state: MachineState,
        connector: FolderSource,
        watch: FolderWatch,
        entry: RemoteFile,
        data: bytes,
        failed: str,
    ) -> None:
        machine = state.config
        folder = self.config.library.inbox

        def keep() -> str:
            with self.sessions.begin() as session:
                row = inbox.store(
                    session,
                    machine.name,
                    data,
                    folder=folder,
                    failed=failed,
                    name=entry.name,
                    remote=watch.remote(entry),
                )
                return row.name

        name = await asyncio.to_thread(keep)
        watch.mark(entry, data)
        if failed:
            message = f"reception of {entry.path} failed: {failed}"
            state.last_error = message
        else:
            message = f"received {entry.path} into the inbox as {name}"
        self.bus.publish(ProgramReceived(machine.name, message))
        if failed or machine.after_receive != "delete":
            return
        # Only now that the reception is committed may the control's copy go.
        error = ""
        try:
            await connector.delete(entry.path)
        except ControlRefused as exc:
            error = str(exc)
            state.last_error = f"{entry.path} received but not deleted: {error}"

        def record() -> None:
            with self.sessions.begin() as session:
                audit.record(
                    session,
                    machine.name,
                    "program.receive.delete",
                    machine=machine.name,
                    program=name,
                    sha256=watch.seen[entry.path.upper()].sha256,
                    result="failed" if error else "ok",
                    path=entry.path,
                    error=error or None,
                )

        await asyncio.to_thread(record)

    def _answer_request(
        self,
        session: Session,
        machine: MachineConfig,
        names: list[str],
        queued: list[dict[str, Any]],
    ) -> str:
        settings = self.config.requests
        due = utcnow() + timedelta(seconds=settings.delay)
        problems: list[str] = []
        sent: list[str] = []
        for name in names:
            try:
                # A rule builds the name from what the operator typed: only a program name
                # is looked up (docs/server.md#receiving-and-remote-request).
                library.check_program_name(name)
            except InputError:
                problems.append(f"{name} NOT A PROGRAM NAME")
                continue
            try:
                version = library.released_version(session, name)
                if version is None and not machine.released_only:
                    version = library.get_version(session, name)
            except NotFound:
                problems.append(f"{name} NOT IN LIBRARY")
                continue
            if version is None:
                problems.append(f"{name} NOT RELEASED")
                continue
            job = jobs.enqueue(
                session,
                JobKind.SEND,
                machine.name,
                actor=f"request@{machine.name}",
                version=version,
                params={"request": True},
                not_before=due,
            )
            queued.append(
                {
                    "job_id": job.id,
                    "machine": machine.name,
                    "job_kind": JobKind.SEND.value,
                    "program": version.program.name,
                    "version": version.number,
                    "by": job.created_by,
                }
            )
            sent.append(name)
        audit.record(
            session,
            machine.name,
            "program.request",
            machine=machine.name,
            requested=names,
            sent=sent,
            refused=problems,
            result="ok" if not problems else "refused",
        )
        if problems and settings.reports != "none":
            self._report(session, machine, "REQUEST FAILED", problems, due)
        elif sent and settings.reports == "all":
            self._report(session, machine, "REQUEST", [f"SENDING {n}" for n in sent], due)
        return f"request for {', '.join(names)}: {len(sent)} queued, {len(problems)} refused"

    def _report(
        self,
        session: Session,
        machine: MachineConfig,
        title: str,
        lines: list[str],
        due: datetime | None = None,
    ) -> None:
        number = self.config.requests.report_program
        text = requests.report_program(number, title, lines).decode("ascii")
        jobs.enqueue(
            session,
            JobKind.REPORT,
            machine.name,
            actor="server",
            not_before=due,
            params={"name": f"O{number:05d}.nc", "report": text},
        )

    @staticmethod
    def _job(job: Claimed, machine: str) -> tuple[int, str, str, str | None, int | None]:
        """The fields every event of ``job`` carries (id, machine, kind, program, version)."""
        program = job.name if job.version is not None else None
        return job.job_id, machine, job.kind.value, program, job.version

    def _fail(
        self, job_id: int, reason: str, retryable: bool, line: int | None, nbytes: int | None
    ) -> str:
        with self.sessions.begin() as session:
            return jobs.fail(
                session,
                job_id,
                reason,
                retryable=retryable,
                backoff=self.retry_backoff,
                line=line,
                nbytes=nbytes,
            ).state.value

    def _finish(self, job_id: int, outcome: dict[str, Any]) -> None:
        with self.sessions.begin() as session:
            jobs.finish(session, job_id, **outcome)

    async def _send(self, state: MachineState, connector: Connector, job: Claimed) -> bool | None:
        program, data = job.name, job.data
        last = [0.0]

        def progress(wire_done: int, wire_total: int | None) -> None:
            # In bytes of the program as stored, whatever the connector counts (an XModem
            # load counts its wire form): one definition of progress everywhere.
            done, total = stored_progress(wire_done, wire_total, len(data))
            state.job_progress = (done, total)
            # A transfer reports every chunk, hundreds a second on a fast link; watchers need
            # a few, and the last one (the API and the cards read job_progress for the rest).
            now = time.monotonic()
            if now - last[0] < PROGRESS_EVERY and (total is None or done < total):
                return
            last[0] = now
            self.bus.publish(
                JobProgress(*self._job(job, state.config.name), bytes_done=done, bytes_total=total)
            )

        await connector.send(program, data, progress)
        verified = await connector.verify(program, data)
        if verified is False:
            raise TransferError(f"{program}: the control holds different bytes after the load")
        return verified


def _last_dprnt_lines(session: Session) -> dict[str, tuple[str, datetime]]:
    """Each machine's newest stored DPRNT line (one query; the (machine, id) index serves it)."""
    newest = select(func.max(DprntLine.id)).group_by(DprntLine.machine)
    rows = session.scalars(select(DprntLine).where(DprntLine.id.in_(newest)))
    return {row.machine: (row.text, row.at) for row in rows}
