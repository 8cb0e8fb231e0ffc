"""The typed results of the actions: what the API answers (its response models) and what
the dashboard's templates show (``model_dump(mode="json")``)."""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime
from typing import Annotated, Literal, Self

from fastapi import Path, Query
from pydantic import BaseModel, ConfigDict, Field, JsonValue, PlainSerializer, field_validator

from opendnc.server.library.versions import History, Listed, VersionRow
from opendnc.server.machines.leases import ClusterView
from opendnc.server.store.models import (
    Job,
    JobKind,
    JobState,
    Program,
    ProgramState,
    ReceivedState,
    Role,
)

# The tables' words the pages and the routes are typed with (a job's kind and state, a
# version's state, a reception's state, a role), so they need not import the tables.
__all__ = [
    "MAX_ID",
    "AuditOut",
    "CheckOut",
    "ClusterOut",
    "ClusterServerOut",
    "Content",
    "Count",
    "DiffOut",
    "FolderOut",
    "FromRow",
    "Id",
    "IdQuery",
    "JobKind",
    "JobOut",
    "JobRequest",
    "JobState",
    "KeyOut",
    "LeaseOut",
    "LineNumber",
    "MachineOut",
    "NetShareOut",
    "ProblemOut",
    "ProgramListed",
    "ProgramOut",
    "ProgramState",
    "ReceivedDetail",
    "ReceivedOut",
    "ReceivedState",
    "ReleaseRequest",
    "RemoteFileOut",
    "RevokedOut",
    "Role",
    "ShareFileOut",
    "ShareFolderOut",
    "ShareMatch",
    "TextMatch",
    "Timestamp",
    "UploadOut",
    "VersionOut",
]

# Ids and counts the database stores in a 32-bit integer column (PostgreSQL's INTEGER): a
# larger one can name nothing, so it is refused at the edge (404/422), never sent to a query.
MAX_ID = 2**31 - 1
Id = Annotated[int, Path(ge=1, le=MAX_ID)]
"""A row id in a URL path (jobs, receptions, keys, version numbers)."""
IdQuery = Annotated[int, Query(ge=1, le=MAX_ID)]
Count = Annotated[int, Query(ge=1, le=10_000)]
"""A ``limit``: at least one row, at most what one page of any list holds."""
LineNumber = Annotated[int, Field(ge=1, le=MAX_ID)]
Timestamp = Annotated[datetime, PlainSerializer(datetime.isoformat, return_type=str)]
"""A time as the server writes it everywhere (``2026-11-27T01:02:03.456789+00:00``, UTC): the
same text in an API answer, an event and a CSV row, so a client may compare them."""


class FromRow(BaseModel):
    """A model read off a row (or a dataclass) attribute by attribute: its fields are named
    as the row's are."""

    model_config = ConfigDict(from_attributes=True)

    @classmethod
    def of(cls, row: object) -> Self:
        """From the row (the relations its fields name loaded with it)."""
        return cls.model_validate(row)


class VersionOut(FromRow):
    """One version of a program."""

    program: str
    number: int
    sha256: str
    size: int
    state: ProgramState
    author: str
    comment: str
    source: str
    created: Timestamp

    @field_validator("program", mode="before")
    @classmethod
    def _program_name(cls, value: object) -> object:
        # a version row names its program through the relation: the model keeps the name
        return value.name if isinstance(value, Program) else value

    @classmethod
    def of_row(cls, program: str, v: VersionRow) -> VersionOut:
        """From a version read as columns."""
        return cls(program=program, **v._asdict())


class ProblemOut(BaseModel):
    """One problem a program check found: the file's 1-based ``line`` (Klartext: also its
    ``block`` number), ``error`` or ``warning``, and what is wrong."""

    line: int
    block: int | None
    severity: str
    message: str


class CheckOut(BaseModel):
    """The program check (dry run) of one version, alone or against a machine.

    ``errors`` block a release and a send unless a programmer overrides them with a reason;
    ``warnings`` are shown. ``problems`` holds at most 500 (the counts are exact); ``facts``
    the checker's tools, extents, distances, estimated ``cycle_time_s`` and units
    (docs/check.md#json, without the moves)."""

    program: str
    version: int
    sha256: str
    machine: str | None
    control: str
    ok: bool
    errors: int
    warnings: int
    summary: str
    problems: list[ProblemOut]
    facts: dict[str, JsonValue]
    checked: Timestamp


class LiveCheckOut(BaseModel):
    """The program check of text being edited (not a stored version): what the editor marks
    as the programmer types. ``problems`` holds at most 500 (the counts are exact)."""

    ok: bool
    errors: int
    warnings: int
    summary: str
    problems: list[ProblemOut]


class UploadOut(VersionOut):
    """A stored upload; ``created_new`` is false when the newest version had these bytes;
    ``check`` is its program check (run on save)."""

    created_new: bool
    check: CheckOut | None = None


class ProgramOut(BaseModel):
    """A program with its versions, oldest first: all of them, or the newest ones when the
    request set a ``limit`` (``version_count`` says how many there are)."""

    name: str
    locked: bool
    created: Timestamp
    version_count: int
    versions: list[VersionOut]

    @classmethod
    def of(cls, p: Program) -> ProgramOut:
        """From the row (its versions loaded with it)."""
        return cls(
            name=p.name,
            locked=p.locked,
            created=p.created,
            version_count=len(p.versions),
            versions=[VersionOut.of(v) for v in p.versions],
        )

    @classmethod
    def of_history(cls, h: History) -> ProgramOut:
        """From the library's history of a program."""
        p = h.program
        return cls(
            name=p.name,
            locked=p.locked,
            created=p.created,
            version_count=h.count,
            versions=[VersionOut.of_row(p.name, v) for v in h.versions],
        )


class TextMatch(BaseModel):
    """Where a search in the program's text found it: the first line of its newest version
    that holds it."""

    line: int
    text: str


class ProgramListed(BaseModel):
    """A program in the library's list: its newest and its released version, how many
    versions it has (``GET /api/programs/{name}`` lists them all), its newest version's title
    (the O-line's comment, Klartext's first comment or name) and where a search in the text
    found it."""

    name: str
    locked: bool
    created: Timestamp
    version_count: int
    newest: VersionOut | None
    released: VersionOut | None
    title: str = ""
    match: TextMatch | None = None

    @classmethod
    def of(cls, listed: Listed) -> ProgramListed:
        """From the library's list entry."""
        p = listed.program
        return cls(
            name=p.name,
            locked=p.locked,
            created=p.created,
            version_count=listed.count,
            newest=VersionOut.of(listed.newest) if listed.newest is not None else None,
            released=VersionOut.of(listed.released) if listed.released is not None else None,
        )


class DiffOut(BaseModel):
    """A unified diff between two versions of a program."""

    program: str
    a: int
    b: int
    lines: list[str]


OVERRIDE = Field(
    default=None,
    max_length=1000,
    description="a reason to go on although the program check found errors (programmers; audited)",
)


class ReleaseRequest(BaseModel):
    """What a release may carry: the override of a program check's errors."""

    override: str | None = OVERRIDE


class JobOut(BaseModel):
    """A job; ``bytes_done``/``bytes_total`` are live while it runs in this server."""

    id: int
    kind: JobKind
    machine: str
    state: JobState
    position: float
    program: str | None
    version: int | None
    sha256: str | None
    params: dict[str, JsonValue]
    attempts: int
    max_attempts: int
    created_by: str
    created: Timestamp
    started: Timestamp | None
    finished: Timestamp | None
    bytes_done: int
    bytes_total: int | None
    error: str
    cancel_requested: bool
    line: int
    server: str | None = Field(
        description="the server that claimed it last (its worker name; several may share a "
        "database)"
    )

    @classmethod
    def of(cls, j: Job, live: tuple[int, int | None] | None = None) -> JobOut:
        """From the row (its version and program loaded with it)."""
        # The live count only while the row says running: a job that ended between the two
        # reads has its final count in the row (the machine's live one lags it by a chunk).
        running = live is not None and j.state is JobState.RUNNING
        done, total = (
            live if running and live is not None else (j.bytes_done, j.bytes_total or None)
        )
        return cls(
            id=j.id,
            kind=j.kind,
            machine=j.machine,
            state=j.state,
            position=j.position,
            program=j.version.program.name if j.version else None,
            version=j.version.number if j.version else None,
            sha256=j.version.sha256 if j.version else None,
            params=dict(j.params),
            attempts=j.attempts,
            max_attempts=j.max_attempts,
            created_by=j.created_by,
            created=j.created,
            started=j.started,
            finished=j.finished,
            bytes_done=done,
            bytes_total=total,
            error=j.error,
            cancel_requested=j.cancel_requested,
            line=j.line,
            server=j.claimed_by,
        )


class AuditOut(FromRow):
    """One row of the audit trail."""

    id: int
    at: Timestamp
    actor: str
    action: str
    machine: str | None
    program: str | None
    sha256: str | None
    job_id: int | None
    result: str
    bytes: int | None
    detail: dict[str, JsonValue]


class ReceivedOut(FromRow):
    """A program received from a control (or a failed try)."""

    id: int
    machine: str
    name: str
    sha256: str
    size: int
    state: ReceivedState
    reason: str
    at: Timestamp
    version_id: int | None


class ReceivedDetail(ReceivedOut):
    """A reception with the library version of its name it is compared with (the released
    one, else the newest) and the unified diff from that version to it."""

    base: VersionOut | None
    diff: list[str]


class KeyOut(BaseModel):
    """A new API key: ``key`` is shown this once and never stored."""

    id: int
    key: str
    user: str
    role: str


class RevokedOut(BaseModel):
    """A revoked key."""

    id: int
    revoked: bool


class StatusOut(BaseModel):
    """What a control said about itself (docs/server.md#machine-status)."""

    model_config = ConfigDict(extra="allow")

    at: Timestamp
    available: bool
    execution: str
    mode: str
    native_mode: str = ""
    program: str
    line: int
    part_count: int | None
    tool: int | None
    overrides: dict[str, float]
    errors: list[str]
    message: str
    dprnt: str = ""
    dprnt_at: Timestamp | None = None


class JobProgressOut(BaseModel):
    """The job a machine runs now, and how far it is."""

    model_config = ConfigDict(extra="allow")

    id: int
    bytes_done: int
    bytes_total: int | None


class MachineOut(BaseModel):
    """A configured machine and its live state."""

    model_config = ConfigDict(extra="allow")

    name: str
    kind: str
    description: str
    released_only: bool
    online: bool
    status: StatusOut | None
    last_error: str
    last_error_at: Timestamp | None
    link_errors: int
    job: JobProgressOut | None


class RemoteFileOut(FromRow):
    """One entry of a folder on a control."""

    name: str
    path: str
    size: int
    modified: Timestamp
    is_dir: bool


class FolderOut(BaseModel):
    """A folder of a control: its entries, folders first, then by name."""

    machine: str
    folder: str
    parent: str | None
    entries: list[RemoteFileOut]


@dataclass(frozen=True)
class Content:
    """Bytes of a version, a reception or a file on a control, with their name and SHA-256."""

    name: str
    sha256: str
    data: bytes


@dataclass(frozen=True)
class Stored:
    """Bytes kept in the database, not read yet: a download streams them in pieces
    (:mod:`opendnc.server.http.downloads`)."""

    name: str
    sha256: str
    size: int


class JobRequest(BaseModel):
    """What a client asks the queue for.

    ``send``, ``dripfeed`` and ``put_file`` name a ``program`` (and optionally its
    ``version``: without it the released one); ``receive``, ``delete``, ``backup`` and
    ``put_file`` name a ``path`` on the control. A send or drip-feed of a version whose
    program check finds errors on a machine is refused unless ``override`` gives a reason
    (programmers; audited).
    """

    kind: JobKind = JobKind.SEND
    program: str | None = Field(default=None, min_length=1, max_length=100)
    version: int | None = Field(default=None, ge=1, le=MAX_ID)
    path: str | None = Field(default=None, min_length=1, max_length=255)
    machines: list[str] = Field(min_length=1, max_length=1000)
    from_line: LineNumber | None = None
    override: str | None = OVERRIDE


class ClusterServerOut(BaseModel):
    """One server sharing the database (several servers, docs/server.md#several-servers)."""

    name: str
    host: str
    pid: int
    url: str
    started: datetime
    heartbeat_age: float = Field(description="seconds since its last heartbeat (database clock)")
    alive: bool
    machines: int = Field(description="machines whose live lease it holds")


class LeaseOut(BaseModel):
    """One machine's lease (``@library``: the library watcher and the net share)."""

    machine: str
    owner: str
    epoch: int
    expires_in: float = Field(description="seconds; negative once expired")
    live: bool


class ClusterOut(BaseModel):
    """The servers of the database and their leases, as ``opendnc cluster status --json``."""

    now: datetime
    servers: list[ClusterServerOut]
    leases: list[LeaseOut]

    @classmethod
    def of(cls, view: ClusterView) -> ClusterOut:
        """The model of a :class:`~opendnc.server.machines.leases.ClusterView`."""
        return cls(
            now=view.now,
            servers=[
                ClusterServerOut.model_validate(s, from_attributes=True) for s in view.servers
            ],
            leases=[LeaseOut.model_validate(row, from_attributes=True) for row in view.leases],
        )


ShareMatch = Literal["same", "differs", "not released", "not in library", "unreadable"]
"""A net share file beside the library: the released version's bytes (``same``), other
bytes (``differs``), a program with no released version (``not released``), no program of
that name, or a file that could not be read just now."""


class ShareFileOut(BaseModel):
    """A program file in a net share folder, beside the library's program of its name
    (names compared without case: SMB shares fold it)."""

    name: str
    size: int
    modified: Timestamp
    sha256: str | None
    library: ShareMatch
    program: str | None = Field(description="the library's program of this name")
    released: int | None = Field(description="its released version, compared with")
    version: int | None = Field(description="the library version with exactly these bytes")
    version_state: ProgramState | None


class ShareFolderOut(BaseModel):
    """The NAS folder (``machine`` None) or a subscribed machine's share, and its files."""

    machine: str | None
    where: str = Field(description="the folder; an SMB one without its login")
    online: bool | None = Field(description="the machine's link (None for the NAS)")
    error: str = Field(description="why the folder could not be listed, or empty")
    files: list[ShareFileOut]


class NetShareOut(BaseModel):
    """The hybrid net share (docs/server.md#hybrid-net-share) as it is now: its folders and
    their files, its archive and schedule, and its newest audit rows."""

    configured: bool
    candidates: list[str] = Field(
        default_factory=list, description="unconfigured: the machines with a share to serve"
    )
    nas: ShareFolderOut | None = None
    machines: list[ShareFolderOut] = Field(default_factory=list)
    archive: str = ""
    archive_at: str | None = Field(default=None, description="HH:MM daily, on the shop's clock")
    archive_every: float | None = Field(default=None, description="or every so many seconds")
    last_archive: Timestamp | None = None
    interval: float = 0.0
    collect: bool = False
    activity: list[AuditOut] = Field(default_factory=list)
