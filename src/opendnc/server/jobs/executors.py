"""One executor per job kind: what running a claimed job means on a machine.

The runner (:mod:`opendnc.server.jobs.runner`) claims a job, finds the executor registered for its
kind and hands it a :class:`JobRun`: the claimed job, the machine's state and connector, and the
way to report progress and to ask whether a cancel was requested (read from the database:
``jobs.cancel_requested`` is the only truth, docs/server.md#jobs). An executor returns what the
job's audit row records, or raises; it never touches the job's state itself.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Protocol

from sqlalchemy.orm import Session, sessionmaker

from opendnc.errors import DncError, InputError, TransferError
from opendnc.haas.dnc_engine import FeedPosition
from opendnc.server.core.events import TransferProgress, stored_progress
from opendnc.server.jobs.queue import RESUME, TAKEN_OVER_FROM
from opendnc.server.kinds.connector import Connector, JobCancelled
from opendnc.server.kinds.files import browser_of, check_path
from opendnc.server.library import inbox
from opendnc.server.machines.state import MachineState
from opendnc.server.store.models import JobKind, utcnow

__all__ = [
    "ALREADY_AT_CONTROL",
    "BackupExecutor",
    "Claimed",
    "DeleteExecutor",
    "DripFeedBroken",
    "DripFeedExecutor",
    "Executor",
    "JobCancelled",
    "JobRun",
    "PutFileExecutor",
    "ReceiveExecutor",
    "ReportExecutor",
    "SendExecutor",
    "default_executors",
    "held_at_control",
    "position_of",
]

log = logging.getLogger(__name__)

PROGRESS_EVERY = 0.1  # seconds between two progress events of one transfer


class DripFeedBroken(DncError):
    """A drip-feed stopped; ``line`` is the program line it had reached, ``nbytes`` the
    program bytes it had fed to get there, ``position`` where exactly it stopped when the
    connector knows (what a continuation starts from: docs/server.md#a-fenced-drip-feed),
    ``stopped_at`` when it had written its last byte at the latest (None: it may still run)."""

    def __init__(
        self,
        reason: str,
        line: int,
        nbytes: int = 0,
        position: FeedPosition | None = None,
        stopped_at: datetime | None = None,
    ) -> None:
        super().__init__(reason)
        self.line = line
        self.nbytes = nbytes
        self.position = position
        self.stopped_at = stopped_at


def position_of(params: dict[str, Any]) -> FeedPosition | None:
    """The position a continuation job starts from (its ``params``), or None."""
    found = params.get(RESUME)
    if not isinstance(found, dict):
        return None
    try:
        return FeedPosition(int(found["offset"]), bytes.fromhex(str(found.get("written", ""))))
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"a continuation's position is not readable: {found!r}") from exc


@dataclass(frozen=True)
class Claimed:
    """A job taken from the queue, with what running it needs."""

    job_id: int
    kind: JobKind
    name: str  # program name, or the path on the control
    data: bytes  # what to send (empty for jobs that take from the control)
    params: dict[str, Any]
    version: int | None = None  # the program version it sends
    attempt: int = 0  # the job's attempts at this claim: which run of the job this is

    @property
    def program(self) -> str | None:
        """The library program it sends (None for jobs that take from the control)."""
        return self.name if self.version is not None else None


ProgressSink = Callable[[TransferProgress], None]
"""Where an executor reports its job's progress: the runner publishes each as a
:class:`~opendnc.server.core.events.JobProgress` (bytes of the program as stored)."""


@dataclass
class JobRun:
    """One claimed job being run on one machine."""

    job: Claimed
    state: MachineState
    connector: Connector
    progress: ProgressSink
    check_cancel: Callable[[], Awaitable[bool]]
    """Ask the database now whether a cancel was requested (a safe point)."""
    cancel_requested: bool = False
    """Set by the runner's watch of the job's row while the job runs; transfers' progress
    callbacks read it between chunks."""
    link_unknown: bool = field(default=False)
    """Set when a transfer was stopped half-way: the link is reopened before the next job."""
    still_driving: Callable[[], None] = field(default=lambda: None)
    """Raises once this server may no longer drive the machine (a fence); from any thread."""

    async def safe_point(self, where: str) -> None:
        """Stop here with :class:`JobCancelled` if a cancel was requested."""
        if self.cancel_requested or await self.check_cancel():
            self.cancel_requested = True
            raise JobCancelled(f"cancelled {where}")


class Executor(Protocol):
    """Runs jobs of one kind."""

    name: str
    needs: tuple[str, ...]
    kind: JobKind

    async def start(self) -> None:
        """Nothing to start by default."""

    async def stop(self) -> None:
        """Nothing to stop by default."""

    async def run(self, run: JobRun) -> dict[str, Any]:
        """Run the job; returns what its audit row records."""


class _Base:
    kind: JobKind
    needs: tuple[str, ...] = ()

    name: str

    async def start(self) -> None:
        """Nothing to start."""

    async def stop(self) -> None:
        """Nothing to stop."""


ALREADY_AT_CONTROL = "already at the control, not sent again"
"""A taken-over load's audit row when the control held its bytes
(docs/server.md#jobs-in-a-cluster)."""
NOT_AT_CONTROL = "the control did not hold these bytes: sent again"
CANNOT_ASK = "the control cannot be asked what it holds: sent again"


async def held_at_control(connector: Connector, name: str, data: bytes) -> bool | None:
    """Whether the control already holds exactly ``data`` as program ``name``: True, False,
    or None where the connector cannot ask (a serial Haas has no file access over its port).

    A connector that can tell has an async ``holds(name, data)``; it is optional beside the
    :class:`~opendnc.server.kinds.connector.Connector` protocol, which every control implements.
    A link error propagates: the load then fails like any other and is retried.
    """
    ask = getattr(connector, "holds", None)
    if ask is None:
        return None
    answer = await ask(name, data)
    return None if answer is None else bool(answer)


class SendExecutor(_Base):
    """A program load: transfer, then read back where the control allows it."""

    kind = JobKind.SEND
    name = "executor.send"

    async def run(self, run: JobRun) -> dict[str, Any]:
        """Load the program; a cancel is honoured before the transfer, between its chunks and
        before the read-back. A load a take-over queued again asks the control first and is
        not sent again if the control already holds these bytes."""
        job, state = run.job, run.state
        checked: dict[str, Any] = {}
        if job.params.get(TAKEN_OVER_FROM):
            await run.safe_point("before asking the control what it holds")
            held = await held_at_control(run.connector, job.name, job.data)
            if held:
                size = len(job.data)
                state.job_progress = (size, size)
                run.progress(TransferProgress(size, size))
                return {
                    "nbytes": size,
                    "verified": True,
                    "verification": ALREADY_AT_CONTROL,
                    "sent": False,
                }
            checked["takeover_check"] = NOT_AT_CONTROL if held is False else CANNOT_ASK
        await run.safe_point("before the transfer")
        last = [0.0]

        def progress(wire_done: int, wire_total: int | None) -> None:
            # In bytes of the program as stored, whatever the connector counts (an XModem
            # load counts its wire form): one definition of progress everywhere.
            done, total = stored_progress(wire_done, wire_total, len(job.data))
            if run.cancel_requested:
                run.link_unknown = True
                raise JobCancelled(f"cancelled after {done} bytes of the program", done)
            state.job_progress = (done, total)
            # A transfer reports every chunk, hundreds a second on a fast link; watchers need
            # a few, and the last one (the API and the cards read job_progress for the rest).
            now = time.monotonic()
            if now - last[0] < PROGRESS_EVERY and (total is None or done < total):
                return
            last[0] = now
            run.progress(TransferProgress(done, total))

        await run.connector.send(job.name, job.data, progress)
        await run.safe_point("after the transfer, before its verification")
        verified = await run.connector.verify(job.name, job.data)
        if verified is False:
            raise TransferError(f"{job.name}: the control holds different bytes after the load")
        # "verified", or why not (a serial Haas: checksum mode only; docs/xmodem.md)
        why = getattr(run.connector, "unverified", None) or "not verified"
        note = "verified" if verified else why
        return {"nbytes": len(job.data), "verified": verified, "verification": note, **checked}


class ReportExecutor(SendExecutor):
    """A report program sent back to the control (a remote request's answer)."""

    kind = JobKind.REPORT
    name = "executor.report"


class DripFeedExecutor(_Base):
    """A program streamed while the machine runs it (the machine's opt-in is checked by the
    connector; the role by the queue)."""

    kind = JobKind.DRIPFEED
    name = "executor.dripfeed"

    async def run(self, run: JobRun) -> dict[str, Any]:
        """Feed from the job's start line; a cancel stops it within one chunk."""
        job, state = run.job, run.state
        from_line = int(job.params.get("from_line", 1))
        resume = position_of(job.params)
        # where the feed stopped, when the connector can say (a fenced feed is continued
        # from there on the machine's next server), and when: told from the feed's thread
        # once it writes no more, so the time does not wait for this event loop
        stops: list[tuple[FeedPosition | None, datetime]] = []
        extra: dict[str, Any] = {}
        if getattr(run.connector, "resumes_feeds", False):
            extra["stopped"] = lambda where: stops.append((where, utcnow()))
            # a feed held by the control's XOFF stops at the fence by itself, not when its
            # link is closed under it (docs/server.md#several-servers)
            extra["waiting"] = run.still_driving
            if resume is not None:
                extra["resume"] = resume
        elif resume is not None:
            raise InputError(f"{state.config.name}: this control's feeds cannot be continued")
        reached = [from_line]
        fed = [0]
        reported = [0.0]  # when the feed last reported progress (time.time())

        def progress(line: int, lines: int, nbytes: int, total: int) -> None:
            # Called from the feed's thread as it goes (a serial Haas's after every line
            # written whole, before its next write): only a new line is news.
            fed[0] = nbytes
            reported[0] = time.time()
            if line != reached[0]:
                reached[0] = line
                # Progress is in bytes like every job's (the card's share and sizes); the line
                # travels beside it for the restart prompt.
                state.job_progress = (nbytes, total or None)
                state.job_line = (line, lines)
                run.progress(TransferProgress(nbytes, total or None, line=line, lines=lines))
            if run.cancel_requested:
                raise JobCancelled(f"cancelled at line {line}")

        await run.safe_point("before the feed")
        try:
            counts = await run.connector.dripfeed(job.name, job.data, from_line, progress, **extra)
        except Exception as exc:
            # Without the thread's word, now: the feed has returned, so it writes no more.
            where, at = stops[-1] if stops else (None, utcnow())
            if where is not None and not where.written and reported[0]:
                # Stopped between two lines: a line written whole is reported before the
                # next write, so the last report follows the last byte (a feed held by XOFF
                # stops only when its link is closed, long after). Part of a line written
                # went out after the last report: then the stop's own time.
                at = datetime.fromtimestamp(reported[0], UTC)
            why = str(exc) or type(exc).__name__
            raise DripFeedBroken(why, reached[0], fed[0], where, stopped_at=at) from exc
        # Progress and the job's bytes are bytes of the stored program (from the start line),
        # as for every job; what went over the wire (EOB, leader, restart preamble) is kept
        # beside them in the audit row.
        wire = counts.get("nbytes")
        return {**counts, "nbytes": fed[0] or wire, "wire_bytes": wire, "from_line": from_line}


class ReceiveExecutor(_Base):
    """A file read from the control into the inbox, under its own name."""

    kind = JobKind.RECEIVE
    name = "executor.receive"

    def __init__(self, sessions: sessionmaker[Session], folder: Path) -> None:
        self.sessions = sessions
        self.folder = folder

    async def run(self, run: JobRun) -> dict[str, Any]:
        """Read the file, keep it in the inbox."""
        await run.safe_point("before the read")
        data = await run.connector.fetch(run.job.name)
        machine = run.state.config.name
        own_name = run.job.name.replace("\\", "/").rsplit("/", 1)[-1].rsplit(":", 1)[-1]

        into_library = bool(run.job.params.get("into_library"))
        actor = str(run.job.params.get("by") or "server")  # who asked for the take-back

        def keep() -> dict[str, Any]:
            with self.sessions.begin() as session:
                row = inbox.store(session, machine, data, folder=self.folder, name=own_name or None)
                out: dict[str, Any] = {"received_id": row.id}
                if into_library:  # a take-back: the inbox's accept, in the same transaction
                    try:
                        with session.begin_nested():
                            version = inbox.accept(session, row.id, actor=actor)
                        out["program"], out["version"] = version.program.name, version.number
                    except DncError as exc:  # locked meanwhile: the file waits in the inbox
                        out["kept_in_inbox"] = str(exc)
                return out

        kept = await asyncio.to_thread(keep)
        return {"nbytes": len(data), "path": run.job.name, **kept}


class DeleteExecutor(_Base):
    """A file deleted on the control."""

    kind = JobKind.DELETE
    name = "executor.delete"

    async def run(self, run: JobRun) -> dict[str, Any]:
        """Delete it (a cancel before that point is honoured)."""
        await run.safe_point("before the delete")
        await run.connector.delete(run.job.name)
        return {"path": run.job.name}


class PutFileExecutor(_Base):
    """A library version written to a path on the control (the file browser's upload: the
    actions layer stored it as a draft and applied the machine's policy)."""

    kind = JobKind.PUT_FILE
    name = "executor.put_file"

    async def run(self, run: JobRun) -> dict[str, Any]:
        """Write the file (a cancel before that point is honoured); one a take-over queued
        again is not written if the control already holds these bytes there."""
        path = check_path(str(run.job.params.get("path", "")))
        checked: dict[str, Any] = {}
        if run.job.params.get(TAKEN_OVER_FROM):
            await run.safe_point("before asking the control what it holds")
            ask = getattr(run.connector, "holds_file", None)
            held = None if ask is None else await ask(path, run.job.data)
            if held:
                size = len(run.job.data)
                return {
                    "nbytes": size,
                    "path": path,
                    "verification": ALREADY_AT_CONTROL,
                    "sent": False,
                }
            checked["takeover_check"] = NOT_AT_CONTROL if held is False else CANNOT_ASK
        await run.safe_point("before the write")

        def progress(done: int, total: int | None) -> None:
            run.state.job_progress = (done, total)

        await browser_of(run.connector).put_file(path, run.job.data, progress)
        return {"nbytes": len(run.job.data), "path": path, **checked}


class BackupExecutor(_Base):
    """A folder of the control copied into the backups."""

    kind = JobKind.BACKUP
    name = "executor.backup"

    def __init__(self, root: Path) -> None:
        self.root = root

    async def run(self, run: JobRun) -> dict[str, Any]:
        """Back up the folder (a cancel before that point is honoured)."""
        await run.safe_point("before the backup")
        counts = await run.connector.backup(run.job.name, self.root / run.state.config.name)
        return {"path": run.job.name, **counts}


def default_executors(
    sessions: sessionmaker[Session], inbox_folder: Path, backups: Path
) -> list[Executor]:
    """One executor for every job kind this server runs."""
    if set(JobKind) - {
        JobKind.SEND,
        JobKind.REPORT,
        JobKind.DRIPFEED,
        JobKind.RECEIVE,
        JobKind.DELETE,
        JobKind.BACKUP,
        JobKind.PUT_FILE,
    }:
        log.warning("some job kinds have no executor; such jobs fail when claimed")
    return [
        SendExecutor(),
        ReportExecutor(),
        DripFeedExecutor(),
        ReceiveExecutor(sessions, inbox_folder),
        DeleteExecutor(),
        PutFileExecutor(),
        BackupExecutor(backups),
    ]


def unknown_kind(kind: JobKind) -> InputError:
    """The error of a job whose kind has no executor here."""
    return InputError(f"{kind.value} jobs are not run by this server version yet")
