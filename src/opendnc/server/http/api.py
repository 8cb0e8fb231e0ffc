"""The JSON API under ``/api/``: a thin adapter over the actions layer.

Each route parses its request, calls one action (:mod:`opendnc.server.actions`) with the
caller and renders the typed result; the roles and the machines' policies are the actions'.
Every route needs an API key (``Authorization: Bearer KEY``) except ``/api/health``; a web
session's cookie is not a key. Routes that touch the database are plain functions, which
FastAPI runs in its thread pool, so a slow query never blocks the event loop that polls the
machines. Errors map to one status each (:func:`opendnc.server.core.errors.http_status`): bad
input 400, no key 401, role too low 403, unknown name 404, state does not allow it 409, too
large 413, bad parameter 422, too many wrong keys 429, machine unreachable 503.
"""

from __future__ import annotations

import json
import logging
import time
from typing import Annotated, Any, Literal

from fastapi import APIRouter, FastAPI, Header, Query, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse, Response, StreamingResponse
from pydantic import BaseModel, Field, JsonValue
from starlette.exceptions import HTTPException as StarletteHTTPException

from opendnc.errors import DncError
from opendnc.server import actions
from opendnc.server.actions.models import (
    MAX_ID,
    AuditOut,
    CheckOut,
    ClusterOut,
    Count,
    DiffOut,
    FolderOut,
    Id,
    IdQuery,
    JobOut,
    JobRequest,
    JobState,
    KeyOut,
    LineNumber,
    MachineOut,
    ProgramListed,
    ProgramOut,
    ReceivedDetail,
    ReceivedOut,
    ReceivedState,
    ReleaseRequest,
    RevokedOut,
    Role,
    UploadOut,
    VersionOut,
)
from opendnc.server.core.components import core_of
from opendnc.server.core.errors import NotFound, TooLarge
from opendnc.server.core.events import Event, JobFinished, Overflow
from opendnc.server.http import deps
from opendnc.server.http.downloads import stored_response
from opendnc.server.http.edge import ApiRoute, error_response
from opendnc.server.http.shared import ERRORS, Caller, Db, Svc, Viewer
from opendnc.server.http.streams import event_stream_response
from opendnc.server.library.versions import MAX_PROGRAM_BYTES, check_program_name
from opendnc.server.machines.state import Machines
from opendnc.server.outputs.shdr import devices_xml

__all__ = ["Db", "Viewer", "install"]

log = logging.getLogger(__name__)

# Server-sent events: at most one update per machine or job per this many seconds.
EVENT_INTERVAL = 0.5


_BINARY = {"schema": {"type": "string", "format": "binary"}}


class OctetStream(Response):
    """Bytes, as they are stored."""

    media_type = "application/octet-stream"


class Xml(Response):
    """An XML document."""

    media_type = "application/xml"


def install(app: FastAPI) -> None:
    """Add the API routes and the error mapping to ``app`` (built by :mod:`opendnc.server.app`,
    whose core holds the actions' :class:`~opendnc.server.actions.Services`)."""
    app.add_exception_handler(DncError, error_response)  # type: ignore[arg-type]
    app.add_exception_handler(RequestValidationError, _invalid)  # type: ignore[arg-type]
    app.add_exception_handler(StarletteHTTPException, _http_error)  # type: ignore[arg-type]
    app.include_router(router)
    app.openapi = lambda: _openapi(app)  # type: ignore[method-assign]


def _openapi(app: FastAPI) -> dict[str, Any]:
    """FastAPI's document, with the bytes, XML, CSV and event-stream answers labelled only
    as what they are: FastAPI adds an empty ``application/json`` beside them, because the
    route's errors are JSON."""
    if app.openapi_schema is None:
        from fastapi.openapi.utils import get_openapi

        doc = get_openapi(
            title=app.title, version=app.version, routes=app.routes, description=app.description
        )
        for operations in doc.get("paths", {}).values():
            for op in operations.values():
                content = op.get("responses", {}).get("200", {}).get("content", {})
                if len(content) > 1 and not content.get("application/json", {}).get("schema"):
                    content.pop("application/json", None)
        app.openapi_schema = doc
    return app.openapi_schema


async def _invalid(_request: Request, exc: RequestValidationError) -> JSONResponse:
    # FastAPI's own answer echoes the input, which fails to encode when it is bytes that are
    # not UTF-8; the location, message and type say enough.
    errors = [
        {"loc": list(e.get("loc", ())), "msg": str(e.get("msg", "")), "type": str(e.get("type"))}
        for e in exc.errors()
    ]
    return JSONResponse({"detail": errors}, status_code=422)


async def _http_error(request: Request, exc: StarletteHTTPException) -> Response:
    detail = exc.detail
    if exc.status_code in (404, 405) and request.url.path.startswith("/api/programs/"):
        # what no route matches there: most often a name with a folder in it
        detail = "no such route; a program name holds no folders ('/')"
    return JSONResponse({"detail": detail}, exc.status_code, headers=exc.headers)


# ApiRoute: request sessions end in the route's thread; JSON bodies hold finite numbers only.
router = APIRouter(prefix="/api", responses=ERRORS, route_class=ApiRoute)

# -- health and outputs ---------------------------------------------------------------------


class DatabaseHealthOut(BaseModel):
    """The database as this server sees it now."""

    ok: bool
    reason: str = Field(
        description="'the database is unavailable' (the server log says why); empty when it answers"
    )
    seconds: float = Field(description="how long it has been in this state")
    answer_ms: float | None = Field(description="the probe's SELECT 1; null when it failed")
    waiting_writes: int = Field(description="job ends waiting for the database to be written")


class LeaseHealthOut(BaseModel):
    """Which machines this server may drive: all of them (a single server) or those whose
    lease it holds (a cluster)."""

    mode: Literal["single", "cluster"]
    serving: int = Field(description="machines this server drives now")
    fenced: bool = Field(description="a cluster server whose leases could have expired")
    valid_for: float | None = Field(description="seconds its leases are still its own")
    renew_failures: int


class HealthOut(BaseModel):
    """Whether the server can do its work: 503 (``unavailable``) while the database is away;
    ``degraded`` when it answers but this cluster server holds no valid lease yet."""

    status: Literal["ok", "degraded", "unavailable"]
    database: DatabaseHealthOut
    leases: LeaseHealthOut
    components: dict[str, str] = Field(description="each component: running or stopped")


@router.get("/health", response_model=HealthOut, responses={503: {"model": HealthOut}})
async def health(request: Request) -> JSONResponse:
    """Health probe; needs no key. Asks the database ``SELECT 1`` (at most 5 s) and answers
    503 when it does not answer. Async: the probe waits on its own thread, so the answer comes
    even while every worker thread is stuck on a silent database."""
    from opendnc.server.cluster.cluster import Cluster

    core = core_of(request.app)
    database = deps.database(request).health
    took = await database.probe()
    cluster = core.find(Cluster)
    if cluster is not None:
        leases = LeaseHealthOut(mode="cluster", **cluster.health())
    else:
        served = sum(s.served for s in deps.machines(request).machines.values())
        leases = LeaseHealthOut(
            mode="single", serving=served, fenced=False, valid_for=None, renew_failures=0
        )
    status: Literal["ok", "degraded", "unavailable"] = "ok"
    if not database.ok:
        status = "unavailable"
    elif leases.fenced:
        status = "degraded"
    out = HealthOut(
        status=status,
        database=DatabaseHealthOut(
            ok=database.ok,
            # never the driver's words: this route needs no key, and they name the database's
            # host, address and user (the log has them, once per outage)
            reason="" if database.ok else "the database is unavailable",
            seconds=round(time.monotonic() - database.since, 3),
            answer_ms=None if took is None else round(took * 1000, 1),
            waiting_writes=deps.runner(request).waiting_writes,
        ),
        leases=leases,
        components=core.states(),
    )
    return JSONResponse(out.model_dump(), status_code=503 if status == "unavailable" else 200)


@router.get("/health/loop")
async def loop_health(request: Request) -> dict[str, JsonValue]:
    """The event loop's stalls (:mod:`opendnc.server.core.loopwatch`); needs no key. Async: it
    reads the watch on the loop, the only thread that writes it."""
    out: dict[str, JsonValue] = deps.loopwatch(request).as_json()
    return out


@router.get("/outputs")
def outputs(request: Request, who: Caller) -> dict[str, dict[str, JsonValue] | None]:
    """The open outputs' state: the MQTT link (connected, queued, dropped) and the SHDR ports
    (agents connected); null for one that is not configured."""
    actions.require(who, Role.VIEWER)
    parts = deps.outputs(request).as_dict()
    return {name: part.as_json() if part is not None else None for name, part in parts.items()}


@router.get("/cluster")
def cluster(svc: Svc, who: Caller) -> ClusterOut:
    """The servers sharing the database, their heartbeats and machine leases (the same as
    ``opendnc cluster status --json``, from any server)."""
    return actions.admin.cluster_status(svc, who)


@router.get(
    "/mtconnect/devices.xml",
    response_model=None,
    responses={200: {"content": {"application/xml": {"schema": {"type": "string"}}}}},
)
def mtconnect_devices(svc: Svc, who: Caller) -> Response:
    """An MTConnect agent's Devices file for the machines the SHDR adapter serves."""
    actions.require(who, Role.VIEWER)
    config = svc.runner.config
    if config.mtconnect is None:
        raise NotFound("no [mtconnect] adapter is configured")
    return Xml(devices_xml([m.name for m in config.machines], config.server.name))


# -- machines -------------------------------------------------------------------------------


@router.get("/machines")
def list_machines(svc: Svc, who: Caller) -> list[MachineOut]:
    """Every configured machine with its live state."""
    return actions.machines.list_machines(svc, who)


@router.get("/machines/{name}")
def get_machine(svc: Svc, name: str, who: Caller) -> MachineOut:
    """One machine with its live state."""
    return actions.machines.get_machine(svc, who, name)


ControlPath = Annotated[str, Query(min_length=1, max_length=255)]


@router.get("/machines/{name}/files")
async def list_machine_files(
    svc: Svc, name: str, who: Caller, path: Annotated[str | None, Query(max_length=255)] = None
) -> FolderOut:
    """A folder of the control (its program folder without ``path``), read on the machine's
    own link between jobs; 409 for a machine without a file browser, 503 while offline."""
    return await actions.files.list_folder(svc, who, name, path)


@router.get(
    "/machines/{name}/files/content",
    response_model=None,
    responses={200: {"content": {"application/octet-stream": _BINARY}}},
)
async def machine_file_content(svc: Svc, name: str, path: ControlPath, who: Caller) -> Response:
    """The bytes of one file of the control, read on the machine's own link."""
    content = await actions.files.read_file(svc, who, name, path)
    return OctetStream(content.data, headers={"X-Content-SHA256": content.sha256})


@router.post("/machines/{name}/files/take-back", status_code=201)
def take_back_machine_file(svc: Svc, name: str, path: ControlPath, who: Caller) -> JobOut:
    """Take a file of the control back into the library (programmers): a ``receive`` job
    that stores it as a new draft version of the program of the file's name; 409 if that
    program is locked or the machine has no file browser."""
    return actions.files.take_back(svc, who, name, path)


# -- library --------------------------------------------------------------------------------


@router.get("/programs")
def list_programs(
    svc: Svc,
    who: Caller,
    q: Annotated[str, Query(max_length=255)] = "",
    text: Annotated[str, Query(max_length=255)] = "",
) -> list[ProgramListed]:
    """Programs in the library with their titles, each with its newest and its released
    version (``/api/programs/{name}`` has every version): ``q`` filters by part of the name
    or title, ``text`` finds programs whose newest version contains it (any case, at most
    100, each with its first matching line)."""
    return actions.library.list_programs(svc, who, q, text)


@router.get("/programs/{name}")
def get_program(svc: Svc, name: str, who: Caller, limit: Count = 200) -> ProgramOut:
    """One program and its newest ``limit`` versions, oldest first (``version_count`` says
    how many it has)."""
    return actions.library.get_program(svc, who, name, limit)


_UPLOAD_BODY = {
    "requestBody": {
        "required": True,
        "description": "the program's bytes, as they go to the control",
        "content": {"application/octet-stream": _BINARY},
    }
}


@router.put("/programs/{name}", status_code=201, openapi_extra=_UPLOAD_BODY)
async def upload_program(
    request: Request,
    svc: Svc,
    name: str,
    who: Caller,
    comment: Annotated[str, Query(max_length=1000)] = "",
    x_content_sha256: Annotated[str | None, Header(max_length=64)] = None,
) -> UploadOut:
    """Store the request body as a new version of ``name`` (a draft)."""
    actions.library.may_upload(who)  # before a byte of the body is read
    check_program_name(name)
    data = await _body(request, MAX_PROGRAM_BYTES)
    return await run_in_threadpool(
        actions.library.upload_program,
        svc,
        who,
        name,
        data,
        comment=comment,
        sha256=x_content_sha256,
    )


async def _body(request: Request, limit: int) -> bytes:
    length = request.headers.get("content-length")
    if length is not None and (not length.isdigit() or int(length) > limit):
        raise TooLarge("the upload is larger than the library takes")
    chunks: list[bytes] = []
    size = 0
    async for chunk in request.stream():
        size += len(chunk)
        if size > limit:  # a chunked body has no length to refuse up front
            raise TooLarge("the upload is larger than the library takes")
        chunks.append(chunk)
    return b"".join(chunks)


@router.get(
    "/programs/{name}/versions/{number}/content",
    response_model=None,
    responses={200: {"content": {"application/octet-stream": _BINARY}}},
)
def program_content(svc: Svc, name: str, number: Id, who: Caller) -> Response:
    """The bytes of one version (streamed as the client reads them)."""
    return stored_response(svc.reads, actions.library.program_stored(svc, who, name, number))


@router.get(
    "/programs/{name}/versions/{number}/toolpath",
    response_model=None,
    responses={200: {"content": {"application/octet-stream": _BINARY}}},
)
def program_toolpath(svc: Svc, name: str, number: Id, who: Caller) -> Response:
    """The dry run's toolpath of one version, decimated to its shape, as little-endian
    binary: runs of points with their kind, tool and file lines (docs/check.md#toolpath-binary)."""
    found = actions.preview.preview(svc, who, name, number)
    return OctetStream(
        found.toolpath,
        headers={
            "X-Content-SHA256": found.sha256,
            "X-Toolpath-Moves": str(found.moves),
            "X-Toolpath-Points": str(found.points),
        },
    )


VersionNumber = Annotated[int, Query(ge=1, le=MAX_ID)]


@router.get("/programs/{name}/diff")
def program_diff(svc: Svc, name: str, a: VersionNumber, b: VersionNumber, who: Caller) -> DiffOut:
    """Unified diff between two versions."""
    return actions.library.program_diff(svc, who, name, a, b)


@router.get("/programs/{name}/versions/{number}/check")
def version_check(
    svc: Svc,
    name: str,
    number: Id,
    who: Caller,
    machine: Annotated[str | None, Query(max_length=64)] = None,
) -> CheckOut:
    """The program check (dry run) of one version: its problems with their lines, tools,
    extents and estimated time; with ``machine``, as that machine would take it (family,
    travel, protected program numbers). Run once and kept."""
    return actions.checks.version_check(svc, who, name, number, machine or None)


@router.post("/programs/{name}/versions/{number}/release")
def release_version(
    svc: Svc, name: str, number: Id, who: Caller, body: ReleaseRequest | None = None
) -> VersionOut:
    """Release a version (the previously released one becomes superseded). A version whose
    program check finds errors is refused (409) unless ``override`` gives a reason
    (programmers; audited)."""
    override = body.override if body is not None else None
    return actions.library.release_version(svc, who, name, number, override)


@router.post("/programs/{name}/lock")
def lock_program(svc: Svc, name: str, who: Caller) -> ProgramOut:
    """Lock a program against new versions and state changes."""
    return actions.library.set_locked(svc, who, name, True)


@router.post("/programs/{name}/unlock")
def unlock_program(svc: Svc, name: str, who: Caller) -> ProgramOut:
    """Unlock a program."""
    return actions.library.set_locked(svc, who, name, False)


# -- jobs -----------------------------------------------------------------------------------


@router.post("/jobs", status_code=201)
def create_jobs(svc: Svc, body: JobRequest, who: Caller, response: Response) -> list[JobOut]:
    """Queue one job on each machine that takes it (201, the jobs); each machine refused is
    named with its reason in the ``OpenDNC-Refused`` header (JSON, ASCII) and the audit
    trail (``job.refused``). Refused on every machine: 409 naming each."""
    queued = actions.queue.queue_each(svc, who, body)
    if queued.refused:
        said = [{"machine": r.machine, "reason": r.reason} for r in queued.refused]
        response.headers[REFUSED_HEADER] = json.dumps(said, ensure_ascii=True)
    return queued.jobs


REFUSED_HEADER = "OpenDNC-Refused"


@router.get("/jobs")
def list_jobs(
    svc: Svc,
    who: Caller,
    machine: Annotated[str | None, Query(max_length=64)] = None,
    state: Annotated[list[JobState] | None, Query()] = None,
    limit: Count = 200,
) -> list[JobOut]:
    """Jobs: the queued ones first in queue order, then the rest newest first."""
    return actions.queue.list_jobs(svc, who, machine=machine, states=state or (), limit=limit)


@router.get("/jobs/{job_id}")
def get_job(svc: Svc, job_id: Id, who: Caller) -> JobOut:
    """One job."""
    return actions.queue.get_job(svc, who, job_id)


@router.post("/jobs/{job_id}/cancel")
def cancel_job(svc: Svc, job_id: Id, who: Caller) -> JobOut:
    """Cancel a queued job, or ask a running one to stop (a drip-feed stops within a chunk)."""
    return actions.queue.cancel_job(svc, who, job_id)


class MoveRequest(BaseModel):
    """New place of a job in its machine's queue (0 = next)."""

    index: int = Field(ge=0, le=MAX_ID)


@router.post("/jobs/{job_id}/move")
def move_job(svc: Svc, job_id: Id, body: MoveRequest, who: Caller) -> JobOut:
    """Reorder the queue."""
    return actions.queue.move_job(svc, who, job_id, body.index)


class RetryRequest(BaseModel):
    """A retry; a drip-feed may restart from a line."""

    from_line: LineNumber | None = None


@router.post("/jobs/{job_id}/retry", status_code=201)
def retry_job(svc: Svc, job_id: Id, who: Caller, body: RetryRequest | None = None) -> JobOut:
    """Queue a failed, interrupted or cancelled job again (a drip-feed: programmers); the
    body is optional."""
    from_line = body.from_line if body is not None else None
    return actions.queue.retry_job(svc, who, job_id, from_line)


# -- audit ----------------------------------------------------------------------------------


@router.get(
    "/audit",
    response_model=list[AuditOut],
    responses={200: {"content": {"text/csv": {"schema": {"type": "string"}}}}},
)
def list_audit(
    svc: Svc,
    who: Caller,
    machine: Annotated[str | None, Query(max_length=64)] = None,
    action: Annotated[str | None, Query(max_length=64)] = None,
    actor: Annotated[str | None, Query(max_length=64)] = None,
    program: Annotated[str | None, Query(max_length=255)] = None,
    limit: Count = 200,
    before: IdQuery | None = None,
    format: Literal["json", "csv"] = "json",
) -> list[AuditOut] | Response:
    """The audit trail, newest first; ``format=csv`` for a spreadsheet."""
    rows = actions.admin.list_audit(
        svc,
        who,
        machine=machine,
        action=action,
        actor=actor,
        program=program,
        limit=limit,
        before=before,
    )
    if format == "csv":
        return actions.admin.audit_csv_response(rows)
    return rows


# -- inbox ----------------------------------------------------------------------------------


@router.get("/inbox")
def list_inbox(
    svc: Svc,
    who: Caller,
    state: Annotated[list[ReceivedState] | None, Query()] = None,
    limit: Count = 200,
) -> list[ReceivedOut]:
    """Programs received from the controls (new ones unless ``state`` says otherwise)."""
    states = state if state is not None else [ReceivedState.NEW]
    return actions.inbox.list_received(svc, who, states, limit)


@router.get("/inbox/{received_id}")
def get_received(svc: Svc, received_id: Id, who: Caller) -> ReceivedDetail:
    """One reception, with its diff against the library program of the same name."""
    return actions.inbox.get_received(svc, who, received_id)


@router.get(
    "/inbox/{received_id}/content",
    response_model=None,
    responses={200: {"content": {"application/octet-stream": _BINARY}}},
)
def received_content(svc: Svc, received_id: Id, who: Caller) -> Response:
    """The received bytes (streamed as the client reads them)."""
    return stored_response(svc.reads, actions.inbox.received_stored(svc, who, received_id))


class AcceptRequest(BaseModel):
    """Accept a reception, optionally under another program name."""

    name: str | None = Field(default=None, max_length=100)


@router.post("/inbox/{received_id}/accept")
def accept_received(
    svc: Svc, received_id: Id, who: Caller, body: AcceptRequest | None = None
) -> VersionOut:
    """Make the reception a new draft version in the library."""
    name = body.name if body is not None else None
    return actions.inbox.accept_received(svc, who, received_id, name)


@router.post("/inbox/{received_id}/discard")
def discard_received(svc: Svc, received_id: Id, who: Caller) -> ReceivedOut:
    """Drop the reception from the inbox."""
    return actions.inbox.discard_received(svc, who, received_id)


# -- keys -----------------------------------------------------------------------------------


class KeyRequest(BaseModel):
    """A new API key."""

    user: str = Field(min_length=1, max_length=64)
    role: str = Field(min_length=1, max_length=16)
    label: str = Field(default="", max_length=128)


@router.post("/keys", status_code=201)
def create_key(svc: Svc, body: KeyRequest, who: Caller) -> KeyOut:
    """Create a key (shown once) for a user; a missing user is created with that role."""
    return actions.admin.create_key(svc, who, body.user, body.role, body.label)


@router.delete("/keys/{key_id}")
def revoke_key(svc: Svc, key_id: Id, who: Caller) -> RevokedOut:
    """Revoke a key."""
    return actions.admin.revoke_key(svc, who, key_id)


# -- events ---------------------------------------------------------------------------------


@router.get(
    "/events",
    response_model=None,
    responses={200: {"content": {"text/event-stream": {"schema": {"type": "string"}}}}},
)
async def events(request: Request, who: Caller) -> StreamingResponse:
    """Server-sent events: a snapshot of every machine, then changes (rate-limited)."""
    actions.require(who, Role.VIEWER)
    machines = deps.machines(request)
    return event_stream_response(
        request, machines.bus, _ApiEvents(machines), interval=EVENT_INTERVAL, who=who.name
    )


def _sse(event: Event) -> bytes:
    data = json.dumps(event.as_json(), separators=(",", ":"))
    return f"event: {event.kind}\ndata: {data}\n\n".encode()


class _ApiEvents:
    """The API's stream: every machine first, then the newest event per machine and per
    job's progress (each start and end of a job, each line and reception kept)."""

    def __init__(self, machines: Machines) -> None:
        self.machines = machines
        self.pending: dict[tuple[str, str], Event] = {}

    async def snapshot(self, overflow: bool) -> bytes:
        self.pending.clear()
        head = _sse(Overflow()) if overflow else b""
        return head + b"".join(_sse(state.event()) for state in self.machines.machines.values())

    def take(self, event: Event) -> None:
        if isinstance(event, JobFinished):
            # the job's last word makes its progress still pending stale
            self.pending.pop((event.kind, str(event.job_id)), None)
        self.pending[(event.kind, event.key)] = event

    async def flush(self) -> bytes:
        out = b"".join(_sse(event) for event in self.pending.values())
        self.pending.clear()
        return out
