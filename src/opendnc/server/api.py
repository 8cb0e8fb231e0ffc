"""The JSON API under ``/api/``: thin routes over the service modules.

Every route needs an API key (``Authorization: Bearer KEY``) except ``/api/health``; every
write names the least role it needs. Routes that touch the database are plain functions, which
FastAPI runs in its thread pool, so a slow query never blocks the event loop that polls the
machines. Service errors map to one status each: bad input 400, no key 401, role too low 403,
unknown name 404, state does not allow it 409.
"""

from __future__ import annotations

import asyncio
import csv
import hashlib
import io
import json
from collections.abc import AsyncIterator
from typing import Annotated, Any

from fastapi import APIRouter, Depends, FastAPI, Header, Query, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse, Response, StreamingResponse
from pydantic import BaseModel, Field
from sqlalchemy.orm import Session, sessionmaker

from opendnc.errors import DncError, InputError
from opendnc.server import audit, auth, dbsession, deps, inbox, jobs, library
from opendnc.server.capabilities import capabilities_of
from opendnc.server.edge import ApiRoute
from opendnc.server.errors import Conflict, Forbidden, NotFound, Unauthorized
from opendnc.server.events import EventBus
from opendnc.server.loopwatch import LoopWatch
from opendnc.server.machine_state import Machines
from opendnc.server.store.models import (
    AuditEntry,
    Job,
    JobKind,
    JobState,
    Program,
    ProgramVersion,
    Received,
    ReceivedState,
    Role,
)

__all__ = ["install"]

STATUS = {NotFound: 404, Conflict: 409, Unauthorized: 401, Forbidden: 403, InputError: 400}
# Server-sent events: at most one update per machine or job per this many seconds.
EVENT_INTERVAL = 0.5


def install(app: FastAPI) -> None:
    """Add the API routes and error mapping to ``app`` (built by :mod:`opendnc.server.app`)."""
    app.add_exception_handler(DncError, _error)  # type: ignore[arg-type]
    app.include_router(router)


async def _error(_request: Request, exc: DncError) -> JSONResponse:
    for cls, status in STATUS.items():
        if isinstance(exc, cls):
            headers = {"WWW-Authenticate": "Bearer"} if status == 401 else None
            return JSONResponse({"detail": str(exc)}, status_code=status, headers=headers)
    return JSONResponse({"detail": str(exc)}, status_code=500)


router = APIRouter(prefix="/api", route_class=ApiRoute)


# Committed when the route returns normally, rolled back when it raises; a route that must
# act after the commit (waking a machine) commits itself first. GET routes read only.
Db = dbsession.Db


def _principal(
    request: Request, authorization: Annotated[str | None, Header()] = None
) -> auth.Principal:
    if not authorization or not authorization.lower().startswith("bearer "):
        raise Unauthorized("send an API key as 'Authorization: Bearer KEY'")
    key = authorization[7:].strip()
    return dbsession.read_then_write(request, lambda session: auth.authenticate_key(session, key))


def require(role: Role) -> Any:
    """A dependency that admits principals with at least ``role``."""

    def check(who: Annotated[auth.Principal, Depends(_principal)]) -> auth.Principal:
        if not who.can(role):
            raise Forbidden(
                f"{who.name} is {who.role.name.lower()}; this needs {role.name.lower()}"
            )
        return who

    return Depends(check)


Viewer = Annotated[auth.Principal, require(Role.VIEWER)]
Operator = Annotated[auth.Principal, require(Role.OPERATOR)]
Programmer = Annotated[auth.Principal, require(Role.PROGRAMMER)]
Approver = Annotated[auth.Principal, require(Role.APPROVER)]
Admin = Annotated[auth.Principal, require(Role.ADMIN)]


def changed(request: Request, kind: str, key: str) -> None:
    """Tell the event stream that the library (``program``) or the inbox (``inbox``) changed
    (after the commit: a page that reloads its list on the event must see the change)."""
    _supervisor(request).bus.publish(kind, key, {"name": key, "source": "request"})


def _supervisor(request: Request) -> Machines:
    return deps.machines(request)


# -- serialisation ------------------------------------------------------------------------


def version_json(v: ProgramVersion) -> dict[str, Any]:
    """A program version as JSON."""
    return {
        "program": v.program.name,
        "number": v.number,
        "sha256": v.sha256,
        "size": v.size,
        "state": v.state.value,
        "author": v.author,
        "comment": v.comment,
        "source": v.source,
        "created": v.created.isoformat(),
    }


def program_json(p: Program) -> dict[str, Any]:
    """A program with its versions as JSON."""
    return {
        "name": p.name,
        "locked": p.locked,
        "created": p.created.isoformat(),
        "versions": [version_json(v) for v in p.versions],
    }


def job_json(j: Job, live: tuple[int, int | None] | None = None) -> dict[str, Any]:
    """A job as JSON (with live progress while it runs here)."""
    done, total = live if live is not None else (j.bytes_done, j.bytes_total or None)
    return {
        "id": j.id,
        "kind": j.kind.value,
        "machine": j.machine,
        "state": j.state.value,
        "position": j.position,
        "program": j.version.program.name if j.version else None,
        "version": j.version.number if j.version else None,
        "sha256": j.version.sha256 if j.version else None,
        "params": j.params,
        "attempts": j.attempts,
        "max_attempts": j.max_attempts,
        "created_by": j.created_by,
        "created": j.created.isoformat(),
        "started": j.started.isoformat() if j.started else None,
        "finished": j.finished.isoformat() if j.finished else None,
        "bytes_done": done,
        "bytes_total": total,
        "error": j.error,
        "cancel_requested": j.cancel_requested,
        "line": j.line,
    }


def audit_json(a: AuditEntry) -> dict[str, Any]:
    """An audit row as JSON."""
    return {
        "id": a.id,
        "at": a.at.isoformat(),
        "actor": a.actor,
        "action": a.action,
        "machine": a.machine,
        "program": a.program,
        "sha256": a.sha256,
        "job_id": a.job_id,
        "result": a.result,
        "bytes": a.bytes,
        "detail": a.detail,
    }


# -- routes -------------------------------------------------------------------------------


@router.get("/health")
def health() -> dict[str, str]:
    """Liveness probe; needs no key."""
    return {"status": "ok"}


@router.get("/health/loop")
async def loop_health(request: Request) -> dict[str, Any]:
    """The event loop's stalls (:mod:`opendnc.server.loopwatch`); needs no key. Async: it
    reads the watch on the loop, the only thread that writes it."""
    watch: LoopWatch = deps.loopwatch(request)
    return watch.as_json()


@router.get("/machines")
def list_machines(request: Request, _who: Viewer) -> list[dict[str, Any]]:
    """Every configured machine with its live state."""
    return [m.as_json() for m in _supervisor(request).machines.values()]


@router.get("/outputs")
def outputs(request: Request, _who: Viewer) -> dict[str, Any]:
    """The open outputs' state: the MQTT link (connected, queued, dropped) and the SHDR ports
    (agents connected); null for one that is not configured."""
    parts = deps.outputs(request).as_dict()
    return {name: part.as_json() if part is not None else None for name, part in parts.items()}


@router.get("/mtconnect/devices.xml")
def mtconnect_devices(request: Request, _who: Viewer) -> Response:
    """An MTConnect agent's Devices file for the machines the SHDR adapter serves."""
    config = _supervisor(request).config
    if config.mtconnect is None:
        raise NotFound("no [mtconnect] adapter is configured")
    from opendnc.server.shdr import devices_xml

    xml = devices_xml([m.name for m in config.machines], config.server.name)
    return Response(xml, media_type="application/xml")


@router.get("/machines/{name}")
def get_machine(request: Request, name: str, _who: Viewer) -> dict[str, Any]:
    """One machine with its live state."""
    state = _supervisor(request).machines.get(name)
    if state is None:
        raise NotFound(f"no machine named {name!r}")
    return state.as_json()


@router.get("/programs")
def list_programs(
    db: Db, _who: Viewer, q: Annotated[str, Query(max_length=library.MAX_SEARCH)] = ""
) -> list[dict[str, Any]]:
    """Programs in the library, optionally filtered by part of the name."""
    return [program_json(p) for p in library.list_programs(db, q)]


@router.get("/programs/{name}")
def get_program(db: Db, name: str, _who: Viewer) -> dict[str, Any]:
    """One program and its versions."""
    return program_json(library.get_program(db, library.check_program_name(name)))


@router.put("/programs/{name}", status_code=201)
async def upload_program(
    request: Request,
    name: str,
    who: Programmer,
    comment: str = "",
    x_content_sha256: Annotated[str | None, Header()] = None,
) -> dict[str, Any]:
    """Store the request body as a new version of ``name`` (a draft)."""
    library.check_program_name(name)
    length = request.headers.get("content-length")
    if length is not None and (not length.isdigit() or int(length) > library.MAX_PROGRAM_BYTES):
        raise InputError("the upload is larger than the library takes")
    data = await request.body()
    if not data:
        raise InputError("the upload is empty")
    if x_content_sha256 and hashlib.sha256(data).hexdigest() != x_content_sha256.lower():
        raise InputError("the upload does not match its X-Content-SHA256 header")

    def store() -> dict[str, Any]:
        sessions: sessionmaker[Session] = deps.database(request).sessions
        with sessions.begin() as session:
            version, created = library.add_version(
                session, name, data, author=who.name, comment=comment
            )
            return {**version_json(version), "created_new": created}

    out = await run_in_threadpool(store)
    changed(request, "program", name)
    return out


@router.put("/programs/{name:path}", status_code=201, include_in_schema=False)
def upload_program_with_a_folder(name: str, _who: Programmer) -> None:
    """A name holding a (decoded) slash matches no other route: refuse it with 400 like every
    other bad name, not 404. ``{name}`` above stays the upload route: ``:path`` would let a
    name end in a newline that the route pattern's ``$`` does not see."""
    library.check_program_name(name)
    raise InputError(f"program name {name[:40]!r}: no folders")


@router.get("/programs/{name}/versions/{number}/content")
def program_content(db: Db, name: str, number: int, _who: Viewer) -> Response:
    """The bytes of one version."""
    version = library.get_version(db, library.check_program_name(name), number)
    return Response(
        library.content(db, version),
        media_type="application/octet-stream",
        headers={"X-Content-SHA256": version.sha256},
    )


@router.get("/programs/{name}/diff")
def program_diff(db: Db, name: str, a: int, b: int, _who: Viewer) -> dict[str, Any]:
    """Unified diff between two versions."""
    return {"program": name, "a": a, "b": b, "lines": library.diff(db, name, a, b)}


@router.post("/programs/{name}/versions/{number}/release")
def release_version(
    request: Request, db: Db, name: str, number: int, who: Approver
) -> dict[str, Any]:
    """Release a version (the previously released one becomes superseded)."""
    out = version_json(
        library.release(db, library.check_program_name(name), number, actor=who.name)
    )
    db.commit()
    changed(request, "program", name)
    return out


@router.post("/programs/{name}/lock")
def lock_program(request: Request, db: Db, name: str, who: Approver) -> dict[str, Any]:
    """Lock a program against new versions and state changes."""
    out = program_json(library.set_locked(db, name, True, actor=who.name))
    db.commit()
    changed(request, "program", name)
    return out


@router.post("/programs/{name}/unlock")
def unlock_program(request: Request, db: Db, name: str, who: Approver) -> dict[str, Any]:
    """Unlock a program."""
    out = program_json(library.set_locked(db, name, False, actor=who.name))
    db.commit()
    changed(request, "program", name)
    return out


class JobRequest(BaseModel):
    """What a client asks the queue for.

    ``send`` and ``dripfeed`` name a ``program`` (and optionally its ``version``);
    ``receive``, ``delete`` and ``backup`` name a ``path`` on the control.
    """

    kind: JobKind = JobKind.SEND
    program: str | None = None
    version: int | None = None
    path: str | None = Field(default=None, min_length=1, max_length=255)
    machines: list[str] = Field(min_length=1, max_length=1000)
    from_line: int | None = Field(default=None, ge=1)


# The least role for each kind of job.
JOB_ROLES = {
    JobKind.SEND: Role.OPERATOR,
    JobKind.RECEIVE: Role.OPERATOR,
    JobKind.BACKUP: Role.OPERATOR,
    JobKind.DRIPFEED: Role.PROGRAMMER,
    JobKind.DELETE: Role.PROGRAMMER,
}


@router.post("/jobs", status_code=201)
def create_jobs(request: Request, db: Db, body: JobRequest, who: Operator) -> list[dict[str, Any]]:
    """Queue one job per machine."""
    needed = JOB_ROLES.get(body.kind)
    if needed is None:
        raise InputError(f"{body.kind.value} jobs are made by the server itself")
    if not who.can(needed):
        raise Forbidden(f"a {body.kind.value} job needs the {needed.name.lower()} role")
    created: list[Job]
    if body.kind in (JobKind.SEND, JobKind.DRIPFEED):
        if body.program is None:
            raise InputError(f"a {body.kind.value} job names a program")
        library.check_program_name(body.program)
        if body.kind is JobKind.SEND:
            created = jobs.send_program(
                db, body.program, body.machines, actor=who.name, number=body.version
            )
        else:
            machines = _supervisor(request).machines
            for name in body.machines:
                state = machines.get(name)
                if state is None:
                    raise NotFound(f"no machine named {name!r}")
                if not capabilities_of(state.config).dripfeed:
                    raise Conflict(f"{name} does not allow drip-feed (dripfeed = true enables it)")
            version = library.get_version(db, body.program, body.version)
            params = {"from_line": body.from_line} if body.from_line else {}
            created = [
                jobs.enqueue(
                    db, JobKind.DRIPFEED, m, actor=who.name, version=version, params=params
                )
                for m in body.machines
            ]
    else:
        if body.path is None or "\x00" in body.path:
            raise InputError(f"a {body.kind.value} job names a path on the control")
        created = [
            jobs.enqueue(db, body.kind, m, actor=who.name, params={"path": body.path})
            for m in body.machines
        ]
    out = [job_json(j) for j in created]
    db.commit()  # before the wake-up, so the machine's claim sees the new rows
    for job in created:
        _supervisor(request).wake(job.machine)
    return out


@router.get("/jobs")
def list_jobs(
    request: Request,
    db: Db,
    _who: Viewer,
    machine: str | None = None,
    state: Annotated[list[JobState] | None, Query()] = None,
    limit: int = 200,
) -> list[dict[str, Any]]:
    """Jobs, the queued ones first in queue order."""
    live = _live_progress(request)
    return [
        job_json(j, live.get(j.id))
        for j in jobs.list_jobs(db, machine=machine, states=state or (), limit=limit)
    ]


def _live_progress(request: Request) -> dict[int, tuple[int, int | None]]:
    return {
        m.job_id: m.job_progress
        for m in _supervisor(request).machines.values()
        if m.job_id is not None
    }


@router.get("/jobs/{job_id}")
def get_job(request: Request, db: Db, job_id: int, _who: Viewer) -> dict[str, Any]:
    """One job."""
    return job_json(jobs.get_job(db, job_id), _live_progress(request).get(job_id))


@router.post("/jobs/{job_id}/cancel")
def cancel_job(request: Request, db: Db, job_id: int, who: Operator) -> dict[str, Any]:
    """Cancel a queued job, or ask a running one to stop (a drip-feed stops within a chunk)."""
    job = jobs.cancel(db, job_id, actor=who.name)
    out = job_json(job)
    db.commit()
    # A running job reads its row's cancel flag at its next safe point (any process's cancel).
    return out


class MoveRequest(BaseModel):
    """New place of a job in its machine's queue (0 = next)."""

    index: int = Field(ge=0)


@router.post("/jobs/{job_id}/move")
def move_job(db: Db, job_id: int, body: MoveRequest, who: Operator) -> dict[str, Any]:
    """Reorder the queue."""
    return job_json(jobs.move(db, job_id, body.index, actor=who.name))


class RetryRequest(BaseModel):
    """A retry; a drip-feed may restart from a line."""

    from_line: int | None = Field(default=None, ge=1)


@router.post("/jobs/{job_id}/retry", status_code=201)
def retry_job(
    request: Request, db: Db, job_id: int, body: RetryRequest, who: Operator
) -> dict[str, Any]:
    """Queue a failed, interrupted or cancelled job again (a drip-feed: programmers)."""
    if jobs.get_job(db, job_id).kind is JobKind.DRIPFEED and not who.can(Role.PROGRAMMER):
        raise Forbidden("restarting a drip-feed needs the programmer role (it runs the machine)")
    job = jobs.retry(db, job_id, actor=who.name, from_line=body.from_line)
    out = job_json(job)
    db.commit()
    _supervisor(request).wake(job.machine)
    return out


@router.get("/audit", response_model=None)
def list_audit(
    db: Db,
    _who: Viewer,
    machine: str | None = None,
    action: str | None = None,
    actor: str | None = None,
    program: str | None = None,
    limit: int = 200,
    before: int | None = None,
    format: str = "json",
) -> list[dict[str, Any]] | Response:
    """The audit trail, newest first; ``format=csv`` for a spreadsheet."""
    rows = [
        audit_json(a)
        for a in audit.query(
            db,
            machine=machine,
            action=action,
            actor=actor,
            program=program,
            limit=limit,
            before_id=before,
        )
    ]
    if format == "csv":
        out = io.StringIO()
        fields = [
            "id",
            "at",
            "actor",
            "action",
            "machine",
            "program",
            "sha256",
            "job_id",
            "result",
            "bytes",
            "detail",
        ]
        writer = csv.DictWriter(out, fields)
        writer.writeheader()
        for row in rows:
            writer.writerow({**row, "detail": json.dumps(row["detail"], sort_keys=True)})
        return Response(
            out.getvalue(),
            media_type="text/csv",
            headers={"Content-Disposition": 'attachment; filename="audit.csv"'},
        )
    if format != "json":
        raise InputError("format is json or csv")
    return rows


def received_json(r: Received) -> dict[str, Any]:
    """A reception as JSON."""
    return {
        "id": r.id,
        "machine": r.machine,
        "name": r.name,
        "sha256": r.sha256,
        "size": r.size,
        "state": r.state.value,
        "reason": r.reason,
        "at": r.at.isoformat(),
        "version_id": r.version_id,
    }


@router.get("/inbox")
def list_inbox(
    db: Db,
    _who: Viewer,
    state: Annotated[list[ReceivedState] | None, Query()] = None,
    limit: int = 200,
) -> list[dict[str, Any]]:
    """Programs received from the controls (new ones unless ``state`` says otherwise)."""
    states = state if state is not None else [ReceivedState.NEW]
    return [received_json(r) for r in inbox.list_received(db, states, limit)]


@router.get("/inbox/{received_id}")
def get_received(db: Db, received_id: int, _who: Viewer) -> dict[str, Any]:
    """One reception, with its diff against the released version of the same name."""
    row = inbox.get(db, received_id)
    return {**received_json(row), "diff": inbox.diff_to_released(db, received_id)}


@router.get("/inbox/{received_id}/content")
def received_content(db: Db, received_id: int, _who: Viewer) -> Response:
    """The received bytes."""
    row = inbox.get(db, received_id)
    return Response(
        inbox.content(db, row),
        media_type="application/octet-stream",
        headers={"X-Content-SHA256": row.sha256},
    )


class AcceptRequest(BaseModel):
    """Accept a reception, optionally under another program name."""

    name: str | None = None


@router.post("/inbox/{received_id}/accept")
def accept_received(
    request: Request, db: Db, received_id: int, body: AcceptRequest, who: Programmer
) -> dict[str, Any]:
    """Make the reception a new draft version in the library."""
    out = version_json(inbox.accept(db, received_id, actor=who.name, name=body.name))
    db.commit()
    changed(request, "inbox", str(received_id))
    changed(request, "program", out["program"])
    return out


@router.post("/inbox/{received_id}/discard")
def discard_received(request: Request, db: Db, received_id: int, who: Programmer) -> dict[str, Any]:
    """Drop the reception from the inbox."""
    out = received_json(inbox.discard(db, received_id, actor=who.name))
    db.commit()
    changed(request, "inbox", str(received_id))
    return out


class KeyRequest(BaseModel):
    """A new API key."""

    user: str
    role: str
    label: str = ""


@router.post("/keys", status_code=201)
def create_key(db: Db, body: KeyRequest, who: Admin) -> dict[str, Any]:
    """Create a key (shown once) for a user; a missing user is created with that role."""
    role = Role.parse(body.role)
    row, key = auth.create_key(
        db, body.user, role, label=body.label, actor=who.name, create_user_role=role
    )
    return {"id": row.id, "key": key, "user": body.user, "role": role.name.lower()}


@router.delete("/keys/{key_id}")
def revoke_key(db: Db, key_id: int, who: Admin) -> dict[str, Any]:
    """Revoke a key."""
    auth.revoke_key(db, key_id, actor=who.name)
    return {"id": key_id, "revoked": True}


@router.get("/events")
async def events(request: Request, _who: Viewer) -> StreamingResponse:
    """Server-sent events: a snapshot of every machine, then changes (rate-limited)."""
    supervisor = _supervisor(request)
    bus: EventBus = supervisor.bus
    return StreamingResponse(
        _event_stream(request, supervisor, bus),
        media_type="text/event-stream",
        headers={"Cache-Control": "no-cache"},
    )


def _sse(kind: str, data: dict[str, Any]) -> bytes:
    return f"event: {kind}\ndata: {json.dumps(data, separators=(',', ':'))}\n\n".encode()


async def _event_stream(
    request: Request, supervisor: Machines, bus: EventBus
) -> AsyncIterator[bytes]:
    with bus.subscribe() as sub:
        for state in supervisor.machines.values():
            yield _sse("machine", state.as_json())
        pending: dict[tuple[str, str], dict[str, Any]] = {}
        loop = asyncio.get_running_loop()
        flush_at = loop.time() + EVENT_INTERVAL
        while not await request.is_disconnected():
            timeout = max(0.0, flush_at - loop.time())
            try:
                # The first event, then everything queued meanwhile, in one go: a wait per
                # event costs the loop more than the event (thousands of progress reports a
                # second while hundreds of transfers run).
                events = [await asyncio.wait_for(sub.get(), timeout), *sub.drain()]
                for event in events:
                    # Keep only the newest event per machine or job until the next flush.
                    pending[(event.kind, event.key)] = event.data
            except TimeoutError:
                pass
            if loop.time() >= flush_at:
                if sub.overflowed:
                    sub.overflowed = False
                    yield _sse("overflow", {})
                for (kind, _key), data in pending.items():
                    yield _sse(kind, data)
                if not pending:
                    yield b": keep-alive\n\n"
                pending.clear()
                flush_at = loop.time() + EVENT_INTERVAL
