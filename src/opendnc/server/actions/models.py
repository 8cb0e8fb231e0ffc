"""The typed results of the actions: what the API answers (its response models) and what
the dashboard's templates show (``model_dump(mode="json")``)."""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime
from typing import Annotated

from fastapi import Path, Query
from pydantic import BaseModel, ConfigDict, Field, JsonValue, PlainSerializer

from opendnc.server.machine_files import RemoteFile
from opendnc.server.store.models import (
    AuditEntry,
    Job,
    JobKind,
    JobState,
    Program,
    ProgramState,
    ProgramVersion,
    Received,
    ReceivedState,
)

__all__ = [
    "MAX_ID",
    "AuditOut",
    "Content",
    "Count",
    "DiffOut",
    "FolderOut",
    "Id",
    "IdQuery",
    "JobOut",
    "JobRequest",
    "KeyOut",
    "LineNumber",
    "MachineOut",
    "ProgramOut",
    "ReceivedDetail",
    "ReceivedOut",
    "RemoteFileOut",
    "RevokedOut",
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


class VersionOut(BaseModel):
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

    @classmethod
    def of(cls, v: ProgramVersion) -> VersionOut:
        """From the row (its program loaded with it)."""
        return cls(
            program=v.program.name,
            number=v.number,
            sha256=v.sha256,
            size=v.size,
            state=v.state,
            author=v.author,
            comment=v.comment,
            source=v.source,
            created=v.created,
        )


class UploadOut(VersionOut):
    """A stored upload; ``created_new`` is false when the newest version had these bytes."""

    created_new: bool


class TextMatch(BaseModel):
    """Where a search in the program's text found it: the first line of its newest version
    that holds it."""

    line: int
    text: str


class ProgramOut(BaseModel):
    """A program with its versions, oldest first; in a list also its newest version's title
    (the O-line's comment, Klartext's first comment or name) and where a search in the text
    found it."""

    name: str
    locked: bool
    created: Timestamp
    versions: list[VersionOut]
    title: str = ""
    match: TextMatch | None = None

    @classmethod
    def of(cls, p: Program) -> ProgramOut:
        """From the row (its versions loaded with it)."""
        return cls(
            name=p.name,
            locked=p.locked,
            created=p.created,
            versions=[VersionOut.of(v) for v in p.versions],
        )


class DiffOut(BaseModel):
    """A unified diff between two versions of a program."""

    program: str
    a: int
    b: int
    lines: list[str]


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

    @classmethod
    def of(cls, j: Job, live: tuple[int, int | None] | None = None) -> JobOut:
        """From the row (its version and program loaded with it)."""
        done, total = live if live is not None else (j.bytes_done, j.bytes_total or None)
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
        )


class AuditOut(BaseModel):
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

    @classmethod
    def of(cls, a: AuditEntry) -> AuditOut:
        """From the row."""
        return cls(
            id=a.id,
            at=a.at,
            actor=a.actor,
            action=a.action,
            machine=a.machine,
            program=a.program,
            sha256=a.sha256,
            job_id=a.job_id,
            result=a.result,
            bytes=a.bytes,
            detail=dict(a.detail),
        )


class ReceivedOut(BaseModel):
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

    @classmethod
    def of(cls, r: Received) -> ReceivedOut:
        """From the row."""
        return cls(
            id=r.id,
            machine=r.machine,
            name=r.name,
            sha256=r.sha256,
            size=r.size,
            state=r.state,
            reason=r.reason,
            at=r.at,
            version_id=r.version_id,
        )


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


class RemoteFileOut(BaseModel):
    """One entry of a folder on a control."""

    name: str
    path: str
    size: int
    modified: Timestamp
    is_dir: bool

    @classmethod
    def of(cls, f: RemoteFile) -> RemoteFileOut:
        """From the connector's listing."""
        return cls(name=f.name, path=f.path, size=f.size, modified=f.modified, is_dir=f.is_dir)


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


class JobRequest(BaseModel):
    """What a client asks the queue for.

    ``send``, ``dripfeed`` and ``put_file`` name a ``program`` (and optionally its
    ``version``: without it the released one); ``receive``, ``delete``, ``backup`` and
    ``put_file`` name a ``path`` on the control.
    """

    kind: JobKind = JobKind.SEND
    program: str | None = Field(default=None, min_length=1, max_length=100)
    version: int | None = Field(default=None, ge=1, le=MAX_ID)
    path: str | None = Field(default=None, min_length=1, max_length=255)
    machines: list[str] = Field(min_length=1, max_length=1000)
    from_line: LineNumber | None = None
