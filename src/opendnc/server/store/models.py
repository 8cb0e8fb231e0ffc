"""The server's tables, as SQLAlchemy 2 declarative models.

The schema itself is owned by the Alembic migrations beside this module (``migrations/``);
these classes only map it. A test compares the two so they cannot drift.

Program content lives in ``blobs`` keyed by its SHA-256: every version that has the same bytes
shares one row, and several servers sharing one database see the same library without a shared
file system.
"""

from __future__ import annotations

import enum
from datetime import UTC, date, datetime
from typing import Any, Final

from sqlalchemy import (
    JSON,
    BigInteger,
    Boolean,
    Date,
    DateTime,
    Enum,
    Float,
    ForeignKey,
    Index,
    Integer,
    LargeBinary,
    MetaData,
    String,
    Text,
    TypeDecorator,
    UniqueConstraint,
    func,
)
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column, relationship

from opendnc.errors import InputError
from opendnc.server.core.jobwords import JobKind, JobState

__all__ = [
    "ApiKey",
    "AuditEntry",
    "Base",
    "Blob",
    "ClusterServer",
    "DowntimeReason",
    "DprntLine",
    "Job",
    "JobKind",
    "JobState",
    "Machine",
    "MachineLease",
    "PartReport",
    "Program",
    "ProgramState",
    "ProgramVersion",
    "Received",
    "ReceivedState",
    "Role",
    "StandardTime",
    "StatusSample",
    "User",
    "UtilizationDay",
    "UtilizationDayMark",
    "UtilizationHour",
    "UtilizationMark",
    "UtilizationProgramHour",
    "UtilizationStretch",
    "UtilizationWeek",
    "VersionCheck",
    "utcnow",
]


# Relationships never load lazily with SQL: a query names what it needs (``selectinload``,
# ``joinedload``), so a hidden query per row (N+1) raises in the tests instead of slowing a
# list of 200 jobs down to 400 queries. An object already in the session's identity map is
# still found without SQL.
NO_LAZY_SQL: Final = "raise_on_sql"


def utcnow() -> datetime:
    """Now, timezone-aware in UTC (every stored time is UTC)."""
    return datetime.now(UTC)


class UtcDateTime(TypeDecorator[datetime]):
    """A DateTime that always comes back timezone-aware in UTC (SQLite keeps no zone)."""

    impl = DateTime(timezone=True)
    cache_ok = True

    def process_bind_param(self, value: datetime | None, dialect: Any) -> datetime | None:
        if value is not None and value.tzinfo is not None:
            value = value.astimezone(UTC)
        return value

    def process_result_value(self, value: datetime | None, dialect: Any) -> datetime | None:
        if value is not None and value.tzinfo is None:
            value = value.replace(tzinfo=UTC)
        return value


class Role(enum.IntEnum):
    """What a user or key may do; each role includes the ones below it."""

    VIEWER = 10  # read everything
    OPERATOR = 20  # send released programs, receive, request, cancel own jobs
    PROGRAMMER = 30  # upload programs and new versions, drip-feed, delete on a control
    APPROVER = 40  # release, supersede and lock versions
    ADMIN = 50  # users, keys, every job

    @classmethod
    def parse(cls, text: str) -> Role:
        """The role named ``text`` (case-insensitive); :class:`InputError` otherwise."""
        try:
            return cls[text.strip().upper()]
        except KeyError:
            names = ", ".join(r.name.lower() for r in cls)
            raise InputError(f"unknown role {text!r} (expected one of {names})") from None


class ProgramState(enum.StrEnum):
    """Life cycle of a program version."""

    DRAFT = "draft"
    RELEASED = "released"
    SUPERSEDED = "superseded"


# Stable constraint names, so Alembic's batch mode can rebuild SQLite tables.
NAMING = {
    "ix": "ix_%(table_name)s_%(column_0_name)s",
    "uq": "uq_%(table_name)s_%(column_0_name)s",
    "ck": "ck_%(table_name)s_%(constraint_name)s",
    "fk": "fk_%(table_name)s_%(column_0_name)s_%(referred_table_name)s",
    "pk": "pk_%(table_name)s",
}


class Base(DeclarativeBase):
    """Declarative base with the naming convention above."""

    metadata = MetaData(naming_convention=NAMING)


def _enum(cls: type[enum.Enum], name: str) -> Enum:
    # Store the values (what the API shows), as plain strings: no database enum type to migrate.
    return Enum(
        cls,
        name=name,
        native_enum=False,
        values_callable=lambda members: [m.value for m in members],
        length=16,
        validate_strings=True,
    )


class User(Base):
    """A person (or service) that logs in or owns API keys."""

    __tablename__ = "users"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    name: Mapped[str] = mapped_column(String(64), unique=True)
    password_hash: Mapped[str | None] = mapped_column(String(256), nullable=True)
    role: Mapped[int] = mapped_column(Integer)
    disabled: Mapped[bool] = mapped_column(Boolean, default=False)
    created: Mapped[datetime] = mapped_column(UtcDateTime(), default=utcnow)

    keys: Mapped[list[ApiKey]] = relationship(back_populates="user", lazy=NO_LAZY_SQL)


class ApiKey(Base):
    """A revocable key; only its SHA-256 is stored, the key itself is shown once."""

    __tablename__ = "api_keys"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    user_id: Mapped[int] = mapped_column(ForeignKey("users.id"))
    prefix: Mapped[str] = mapped_column(String(16))  # shown in lists to tell keys apart
    key_hash: Mapped[str] = mapped_column(String(64), unique=True)
    role: Mapped[int] = mapped_column(Integer)  # never above the user's own role
    label: Mapped[str] = mapped_column(String(128), default="")
    created: Mapped[datetime] = mapped_column(UtcDateTime(), default=utcnow)
    revoked: Mapped[datetime | None] = mapped_column(UtcDateTime(), nullable=True)
    last_used: Mapped[datetime | None] = mapped_column(UtcDateTime(), nullable=True)

    user: Mapped[User] = relationship(back_populates="keys", lazy=NO_LAZY_SQL)


class Machine(Base):
    """A configured machine; the row exists so jobs can lock their port across servers."""

    __tablename__ = "machines"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    name: Mapped[str] = mapped_column(String(64), unique=True)
    kind: Mapped[str] = mapped_column(String(16))
    released_only: Mapped[bool] = mapped_column(Boolean, default=False)


class Blob(Base):
    """Program bytes, addressed by their SHA-256."""

    __tablename__ = "blobs"

    sha256: Mapped[str] = mapped_column(String(64), primary_key=True)
    size: Mapped[int] = mapped_column(BigInteger)
    data: Mapped[bytes] = mapped_column(LargeBinary)


class Program(Base):
    """A program name in the library (``O01234``, ``POCKET.H``) and its versions."""

    __tablename__ = "programs"
    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    name: Mapped[str] = mapped_column(String(255), unique=True)
    locked: Mapped[bool] = mapped_column(Boolean, default=False)
    created: Mapped[datetime] = mapped_column(UtcDateTime(), default=utcnow)

    versions: Mapped[list[ProgramVersion]] = relationship(
        back_populates="program", order_by="ProgramVersion.number", lazy=NO_LAZY_SQL
    )


# Names that differ only in case are one file on Windows and SMB shares: the database refuses
# the second even when two uploads race (docs/server.md#program-names).
Index("uq_programs_name_folded", func.lower(Program.name), unique=True)


class ProgramVersion(Base):
    """One kept version of a program."""

    __tablename__ = "program_versions"
    __table_args__ = (UniqueConstraint("program_id", "number", name="uq_program_versions_number"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    program_id: Mapped[int] = mapped_column(ForeignKey("programs.id"))
    number: Mapped[int] = mapped_column(Integer)
    sha256: Mapped[str] = mapped_column(ForeignKey("blobs.sha256"))
    size: Mapped[int] = mapped_column(BigInteger)
    state: Mapped[ProgramState] = mapped_column(_enum(ProgramState, "program_state"))
    author: Mapped[str] = mapped_column(String(64))
    comment: Mapped[str] = mapped_column(Text, default="")
    source: Mapped[str] = mapped_column(String(32), default="upload")  # upload, watcher, inbox
    created: Mapped[datetime] = mapped_column(UtcDateTime(), default=utcnow)

    program: Mapped[Program] = relationship(back_populates="versions", lazy=NO_LAZY_SQL)


class Job(Base):
    """A durable unit of work on one machine."""

    __tablename__ = "jobs"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    kind: Mapped[JobKind] = mapped_column(_enum(JobKind, "job_kind"))
    machine: Mapped[str] = mapped_column(ForeignKey("machines.name"), index=True)
    state: Mapped[JobState] = mapped_column(_enum(JobState, "job_state"), index=True)
    position: Mapped[float] = mapped_column(Float)  # order within the machine's queue
    version_id: Mapped[int | None] = mapped_column(ForeignKey("program_versions.id"), nullable=True)
    params: Mapped[dict[str, Any]] = mapped_column(JSON, default=dict)
    attempts: Mapped[int] = mapped_column(Integer, default=0)
    max_attempts: Mapped[int] = mapped_column(Integer, default=3)
    not_before: Mapped[datetime | None] = mapped_column(UtcDateTime(), nullable=True)
    created_by: Mapped[str] = mapped_column(String(64))
    created: Mapped[datetime] = mapped_column(UtcDateTime(), default=utcnow)
    started: Mapped[datetime | None] = mapped_column(UtcDateTime(), nullable=True)
    finished: Mapped[datetime | None] = mapped_column(UtcDateTime(), nullable=True)
    claimed_by: Mapped[str | None] = mapped_column(String(64), nullable=True)
    cancel_requested: Mapped[bool] = mapped_column(Boolean, default=False)
    bytes_done: Mapped[int] = mapped_column(BigInteger, default=0)
    bytes_total: Mapped[int] = mapped_column(BigInteger, default=0)
    line: Mapped[int] = mapped_column(Integer, default=0)
    error: Mapped[str] = mapped_column(Text, default="")

    version: Mapped[ProgramVersion | None] = relationship(lazy=NO_LAZY_SQL)


class ReceivedState(enum.StrEnum):
    """Where a program received from a control is."""

    NEW = "new"  # waiting in the inbox for a person
    ACCEPTED = "accepted"  # became a library version
    DISCARDED = "discarded"
    FAILED = "failed"  # the reception broke off; kept with its reason


class Received(Base):
    """A program that came from a control (a punch, a file found on it), or a failed try."""

    __tablename__ = "received"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    machine: Mapped[str] = mapped_column(String(64), index=True)
    name: Mapped[str] = mapped_column(String(255))
    sha256: Mapped[str] = mapped_column(ForeignKey("blobs.sha256"))
    size: Mapped[int] = mapped_column(BigInteger)
    state: Mapped[ReceivedState] = mapped_column(_enum(ReceivedState, "received_state"))
    reason: Mapped[str] = mapped_column(Text, default="")
    path: Mapped[str] = mapped_column(Text, default="")  # the file written to the inbox folder
    at: Mapped[datetime] = mapped_column(UtcDateTime(), default=utcnow)
    version_id: Mapped[int | None] = mapped_column(ForeignKey("program_versions.id"), nullable=True)


class AuditEntry(Base):
    """One row of the append-only audit trail (database triggers refuse updates and deletes)."""

    __tablename__ = "audit"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    at: Mapped[datetime] = mapped_column(UtcDateTime(), default=utcnow, index=True)
    actor: Mapped[str] = mapped_column(String(64))
    action: Mapped[str] = mapped_column(String(64), index=True)
    machine: Mapped[str | None] = mapped_column(String(64), nullable=True, index=True)
    program: Mapped[str | None] = mapped_column(String(255), nullable=True)
    sha256: Mapped[str | None] = mapped_column(String(64), nullable=True)
    job_id: Mapped[int | None] = mapped_column(Integer, nullable=True)
    result: Mapped[str] = mapped_column(String(16), default="ok")
    bytes: Mapped[int | None] = mapped_column(BigInteger, nullable=True)
    detail: Mapped[dict[str, Any]] = mapped_column(JSON, default=dict)


class DprntLine(Base):
    """One line a Haas printed with DPRNT, as the server captured it (``complete`` is False
    for a line cut short by the end of the link)."""

    __tablename__ = "dprnt_lines"
    # read as "this machine's lines after id N": one index serves it
    __table_args__ = (Index("ix_dprnt_lines_machine_id", "machine", "id"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    machine: Mapped[str] = mapped_column(String(64))
    at: Mapped[datetime] = mapped_column(UtcDateTime(), default=utcnow)
    text: Mapped[str] = mapped_column(Text)
    fields: Mapped[list[Any]] = mapped_column(JSON, default=list)  # [{"label", "value"}, ...]
    complete: Mapped[bool] = mapped_column(Boolean, default=True)


class StatusSample(Base):
    """A machine's state from ``at`` until its next sample (changes only), for the status
    timeline: ``state`` is the strip's colour (offline, active, ready, stopped, alarm, or
    ``none`` from a server stop until the next start), ``mode`` and ``execution`` the control's
    words. Pruned after ``[server] timeline_retention_days``."""

    __tablename__ = "status_samples"
    # read as "this machine's samples since a time", pruned as "everything before a time"
    __table_args__ = (
        Index("ix_status_samples_machine_at", "machine", "at"),
        Index("ix_status_samples_at", "at"),
    )

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    machine: Mapped[str] = mapped_column(String(64))
    at: Mapped[datetime] = mapped_column(UtcDateTime(), default=utcnow)
    state: Mapped[str] = mapped_column(String(16))
    mode: Mapped[str] = mapped_column(String(64), default="")
    execution: Mapped[str] = mapped_column(String(32), default="")
    # for utilization (migration 0007): what ran, the control's part counter, the alarm's text
    program: Mapped[str] = mapped_column(String(64), default="")
    part_count: Mapped[int | None] = mapped_column(Integer, nullable=True, default=None)
    alarm: Mapped[str] = mapped_column(String(200), default="")


class UtilizationHour(Base):
    """One machine's hour (UTC) of the status timeline, summed (server/utilization/collect.py): the
    seconds in each state, parts counted, program runs that ended in it and their running
    seconds. Written once the hour is over; kept when the samples are pruned."""

    __tablename__ = "utilization_hours"

    machine: Mapped[str] = mapped_column(String(64), primary_key=True)
    hour: Mapped[datetime] = mapped_column(UtcDateTime(), primary_key=True)
    running: Mapped[float] = mapped_column(Float, default=0.0)
    ready: Mapped[float] = mapped_column(Float, default=0.0)
    stopped: Mapped[float] = mapped_column(Float, default=0.0)
    alarm: Mapped[float] = mapped_column(Float, default=0.0)
    offline: Mapped[float] = mapped_column(Float, default=0.0)
    unknown: Mapped[float] = mapped_column(Float, default=0.0)
    no_record: Mapped[float] = mapped_column(Float, default=0.0)
    parts: Mapped[int | None] = mapped_column(Integer, nullable=True, default=None)
    runs: Mapped[int] = mapped_column(Integer, default=0)
    cycles: Mapped[int] = mapped_column(Integer, default=0)  # runs whose running time is known
    cycle_seconds: Mapped[float] = mapped_column(Float, default=0.0)


class UtilizationProgramHour(Base):
    """One machine's runs of one program (by its library key, oee.program_key) that ended in
    an hour (UTC), and the program's running seconds in it: what OEE's performance reads,
    summed with the hours (server/utilization/collect.py, migration 0023) and kept with
    them."""

    __tablename__ = "utilization_program_hours"

    machine: Mapped[str] = mapped_column(String(64), primary_key=True)
    hour: Mapped[datetime] = mapped_column(UtcDateTime(), primary_key=True)
    program: Mapped[str] = mapped_column(String(64), primary_key=True)
    runs: Mapped[int] = mapped_column(Integer, default=0)
    seconds: Mapped[float] = mapped_column(Float, default=0.0)


class UtilizationStretch(Base):
    """A finished stop (``kind`` stop: 5 minutes or more not running) or alarm (``kind``
    alarm, any length, with its text) of one machine, kept with the hours."""

    __tablename__ = "utilization_stretches"
    __table_args__ = (
        # (on PostgreSQL carrying what a question reads of an alarm: the alarms of a year
        # per text are then read from the index alone, not from all over the table)
        Index(
            "ix_utilization_stretches_machine_end",
            "machine",
            "kind",
            "end",
            postgresql_include=["start", "seconds", "state", "text"],
        ),
        Index("ix_utilization_stretches_machine_seconds", "machine", "kind", "seconds"),
        # (a stop is named by its start: a reason picked for it finds its length here)
        Index("ix_utilization_stretches_machine_start", "machine", "kind", "start"),
    )

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    machine: Mapped[str] = mapped_column(String(64))
    kind: Mapped[str] = mapped_column(String(8))  # stop, alarm
    start: Mapped[datetime] = mapped_column(UtcDateTime())
    end: Mapped[datetime] = mapped_column(UtcDateTime())
    seconds: Mapped[float] = mapped_column(Float)
    state: Mapped[str] = mapped_column(String(16))  # a stop's worst state
    text: Mapped[str] = mapped_column(String(200), default="")


class UtilizationMark(Base):
    """How far one machine's hours are summed (``until``), the highest sample id read, and
    what carries over into the next hour (a run, a stop or an alarm in progress)."""

    __tablename__ = "utilization_marks"

    machine: Mapped[str] = mapped_column(String(64), primary_key=True)
    until: Mapped[datetime] = mapped_column(UtcDateTime())
    last_id: Mapped[int] = mapped_column(Integer, default=0)
    carry: Mapped[dict[str, Any]] = mapped_column(JSON, default=dict)


class UtilizationDay(Base):
    """One machine's local day of the shop's calendar in one slot (a shift's part of it, or
    ``shift`` empty: the time outside shifts), summed from its finished hours
    (server/utilization/days.py, migration 0014). ``shift_day`` is the day the shift began
    (the day before for the morning part of a night shift). Kept per calendar: a changed
    ``[server] timezone`` or ``[[shifts]]`` builds them again from the hours."""

    __tablename__ = "utilization_days"

    machine: Mapped[str] = mapped_column(String(64), primary_key=True)
    day: Mapped[date] = mapped_column(Date, primary_key=True)
    shift: Mapped[str] = mapped_column(String(32), primary_key=True)
    shift_day: Mapped[date] = mapped_column(Date, primary_key=True)
    week: Mapped[date] = mapped_column(Date)  # the Monday of the day's ISO week
    running: Mapped[float] = mapped_column(Float, default=0.0)
    ready: Mapped[float] = mapped_column(Float, default=0.0)
    stopped: Mapped[float] = mapped_column(Float, default=0.0)
    alarm: Mapped[float] = mapped_column(Float, default=0.0)
    offline: Mapped[float] = mapped_column(Float, default=0.0)
    unknown: Mapped[float] = mapped_column(Float, default=0.0)
    no_record: Mapped[float] = mapped_column(Float, default=0.0)
    parts: Mapped[int | None] = mapped_column(Integer, nullable=True, default=None)
    runs: Mapped[int] = mapped_column(Integer, default=0)
    cycles: Mapped[int] = mapped_column(Integer, default=0)
    cycle_seconds: Mapped[float] = mapped_column(Float, default=0.0)


class UtilizationWeek(Base):
    """One machine's week of the shop's calendar (``week``: its Monday), the sum of its day
    rows (server/utilization/days.py, migration 0016): the seconds in each state, and within
    shifts (``shift_``), as a question over months groups them by week. Written once the
    week's last day is summed; dropped with its days."""

    __tablename__ = "utilization_weeks"

    machine: Mapped[str] = mapped_column(String(64), primary_key=True)
    week: Mapped[date] = mapped_column(Date, primary_key=True)
    running: Mapped[float] = mapped_column(Float, default=0.0)
    ready: Mapped[float] = mapped_column(Float, default=0.0)
    stopped: Mapped[float] = mapped_column(Float, default=0.0)
    alarm: Mapped[float] = mapped_column(Float, default=0.0)
    offline: Mapped[float] = mapped_column(Float, default=0.0)
    unknown: Mapped[float] = mapped_column(Float, default=0.0)
    no_record: Mapped[float] = mapped_column(Float, default=0.0)
    shift_running: Mapped[float] = mapped_column(Float, default=0.0)
    shift_ready: Mapped[float] = mapped_column(Float, default=0.0)
    shift_stopped: Mapped[float] = mapped_column(Float, default=0.0)
    shift_alarm: Mapped[float] = mapped_column(Float, default=0.0)
    shift_offline: Mapped[float] = mapped_column(Float, default=0.0)
    shift_unknown: Mapped[float] = mapped_column(Float, default=0.0)
    shift_no_record: Mapped[float] = mapped_column(Float, default=0.0)
    parts: Mapped[int | None] = mapped_column(Integer, nullable=True, default=None)
    runs: Mapped[int] = mapped_column(Integer, default=0)
    cycles: Mapped[int] = mapped_column(Integer, default=0)
    cycle_seconds: Mapped[float] = mapped_column(Float, default=0.0)


class UtilizationDayMark(Base):
    """Up to which local midnight (``until``, UTC) one machine's days are summed, and for
    which calendar (a digest of the zone and the shifts)."""

    __tablename__ = "utilization_day_marks"

    machine: Mapped[str] = mapped_column(String(64), primary_key=True)
    calendar: Mapped[str] = mapped_column(String(64))
    until: Mapped[datetime] = mapped_column(UtcDateTime())
    # up to which local midnight the stops' lost time per reason is summed (migration 0020):
    # never past the start of a stop still going; None: not begun
    lost_until: Mapped[datetime | None] = mapped_column(UtcDateTime(), nullable=True)


class UtilizationLostDay(Base):
    """The stops of one machine that began in one slot of a local day (as in
    ``utilization_days``), per downtime reason (``reason`` empty: none picked yet): how many
    and their seconds (server/utilization/lost.py, migration 0020). Summed once every stop
    that began that day is over; a reason picked later sums the day again."""

    __tablename__ = "utilization_lost_days"

    machine: Mapped[str] = mapped_column(String(64), primary_key=True)
    day: Mapped[date] = mapped_column(Date, primary_key=True)
    shift: Mapped[str] = mapped_column(String(32), primary_key=True)
    shift_day: Mapped[date] = mapped_column(Date, primary_key=True)
    reason: Mapped[str] = mapped_column(String(64), primary_key=True)
    week: Mapped[date] = mapped_column(Date)
    stops: Mapped[int] = mapped_column(Integer, default=0)
    seconds: Mapped[float] = mapped_column(Float, default=0.0)


class UtilizationLostWeek(Base):
    """The rows of ``utilization_lost_days`` of one machine and week summed per reason,
    written when the week's last day is (migration 0020)."""

    __tablename__ = "utilization_lost_weeks"

    machine: Mapped[str] = mapped_column(String(64), primary_key=True)
    week: Mapped[date] = mapped_column(Date, primary_key=True)
    reason: Mapped[str] = mapped_column(String(64), primary_key=True)
    stops: Mapped[int] = mapped_column(Integer, default=0)
    seconds: Mapped[float] = mapped_column(Float, default=0.0)


class ClusterServer(Base):
    """A server of a cluster sharing one PostgreSQL database, and when it last said it lives.

    ``heartbeat`` is the database's clock, never the server's: servers whose clocks disagree
    still agree on who is alive (docs/server.md#several-servers).
    """

    __tablename__ = "cluster_servers"

    name: Mapped[str] = mapped_column(String(64), primary_key=True)
    host: Mapped[str] = mapped_column(String(255), default="")
    pid: Mapped[int] = mapped_column(Integer, default=0)
    url: Mapped[str] = mapped_column(String(255), default="")
    lease_seconds: Mapped[float] = mapped_column(Float, default=10.0)  # alive within this
    started: Mapped[datetime] = mapped_column(UtcDateTime())
    heartbeat: Mapped[datetime] = mapped_column(UtcDateTime())


class MachineLease(Base):
    """Which server serves a machine until ``expires`` (the database's clock).

    ``epoch`` grows by one at every change of owner: a server that lost its lease while it
    was paused cannot act on the machine's rows with a stale epoch.
    """

    __tablename__ = "machine_leases"

    machine: Mapped[str] = mapped_column(String(64), primary_key=True)
    owner: Mapped[str] = mapped_column(String(64), default="")
    epoch: Mapped[int] = mapped_column(BigInteger, default=0)
    acquired: Mapped[datetime] = mapped_column(UtcDateTime())
    expires: Mapped[datetime] = mapped_column(UtcDateTime())


class MachineSnapshot(Base):
    """A machine as its serving server last saw it, for the other servers of a cluster.

    The server that holds a machine's lease writes its status here (what ``/api/machines``
    shows for it) several times a second; every other server reads the rows it does not
    serve, so the dashboard, the API, the event streams and MTConnect are the same on every
    server (:mod:`opendnc.server.fleet.shared_status`). ``data`` is rewritten only when something
    but the status's time changed (``changed``); each poll moves ``polled``, the time of the
    status the row stands for. ``updated`` and ``changed`` are the database's clock (the
    writing transaction's start): a reader asks for rows newer than the last it saw.
    """

    __tablename__ = "machine_snapshots"

    machine: Mapped[str] = mapped_column(String(64), primary_key=True)
    server: Mapped[str] = mapped_column(String(64), default="")
    updated: Mapped[datetime] = mapped_column(UtcDateTime(), index=True)
    data: Mapped[dict[str, Any]] = mapped_column(JSON, default=dict)
    changed: Mapped[datetime | None] = mapped_column(UtcDateTime(), nullable=True)
    polled: Mapped[datetime | None] = mapped_column(UtcDateTime(), nullable=True)


class SparkplugNode(Base):
    """A Sparkplug B edge node's birth/death sequence number (``bdSeq``), kept across restarts.

    ``bd_seq`` is the number of the node's latest MQTT session: each new session takes the next
    one (0..255, then 0 again), so a host can tell a late NDEATH of an old session from the
    current one (docs/server.md#sparkplug-b).
    """

    __tablename__ = "sparkplug_nodes"

    group_id: Mapped[str] = mapped_column(String(64), primary_key=True)
    node_id: Mapped[str] = mapped_column(String(64), primary_key=True)
    bd_seq: Mapped[int] = mapped_column(Integer, default=0)


class VersionCheck(Base):
    """The dry run of one program version (:mod:`opendnc.nccheck`), kept so a page, a release
    and a send read it instead of running it again: ``limits`` is ``""`` for the check of the
    text alone, else a digest of the machine limits it ran against (family, travel, work
    offsets, protected numbers), so machines alike share one row and a changed configuration
    makes a new one. ``problems`` holds ``{line, block, severity, message}`` each."""

    __tablename__ = "version_checks"
    __table_args__ = (
        UniqueConstraint("version_id", "limits", name="uq_version_checks_version_limits"),
    )

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    version_id: Mapped[int] = mapped_column(ForeignKey("program_versions.id"))
    limits: Mapped[str] = mapped_column(String(64), default="")
    control: Mapped[str] = mapped_column(String(16))
    errors: Mapped[int] = mapped_column(Integer, default=0)
    warnings: Mapped[int] = mapped_column(Integer, default=0)
    summary: Mapped[str] = mapped_column(Text, default="")
    problems: Mapped[list[Any]] = mapped_column(JSON, default=list)
    facts: Mapped[dict[str, Any]] = mapped_column(JSON, default=dict)  # tools, extents, time
    checked: Mapped[datetime] = mapped_column(UtcDateTime(), default=utcnow)


class ServerSecret(Base):
    """A secret every server on this database shares, made once by the first that needs it
    (:func:`opendnc.server.store.secrets.shared_secret`): the key that signs the browsers'
    device cookies, so a cookie one server of a cluster issued is good on the others and
    after a restart (docs/server.md#throttling)."""

    __tablename__ = "server_secrets"

    name: Mapped[str] = mapped_column(String(64), primary_key=True)
    value: Mapped[bytes] = mapped_column(LargeBinary)
    created: Mapped[datetime] = mapped_column(UtcDateTime(), default=utcnow)


class AlertEpisode(Base):
    """An alert episode that fired and has not ended: the alert went out (``fired``, by
    ``server``) for the condition of ``rule`` on ``machine`` that began at ``since``.

    The row is the claim: the server that inserts it sends the alert, one that finds it there
    does not (after a restart, on another server of the cluster); the server that deletes it
    when the condition ends sends the "cleared" alert (docs/server.md#alerts).
    """

    __tablename__ = "alert_episodes"

    rule: Mapped[str] = mapped_column(String(128), primary_key=True)
    machine: Mapped[str] = mapped_column(String(64), primary_key=True)
    since: Mapped[datetime] = mapped_column(UtcDateTime())
    fired: Mapped[datetime] = mapped_column(UtcDateTime())
    server: Mapped[str] = mapped_column(String(64), default="")
    detail: Mapped[str] = mapped_column(Text, default="")


class AlertedJob(Base):
    """A failed job whose alert one server claimed before sending it (migration 0022).

    The row is the claim (:func:`opendnc.server.store.claims.claim_once`): the server whose
    insert goes through sends the job's alerts to every target, any other (another server of
    the cluster that also saw the job end, this one after a restart) finds the row and sends
    nothing. A server killed mid-send leaves the row: the alert is not sent again, and the
    audit trail's ``alert`` rows show what went (docs/server.md#alerts). ``job_id`` is no
    foreign key: a refused insert must only ever mean "claimed already"."""

    __tablename__ = "alerted_jobs"

    job_id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=False)
    machine: Mapped[str] = mapped_column(String(64))
    server: Mapped[str] = mapped_column(String(64), default="")
    claimed: Mapped[datetime] = mapped_column(UtcDateTime(), default=utcnow)


class StandardTime(Base):
    """A supervisor's standard cycle time for one program version (OEE's ideal cycle,
    server/utilization/oee.py, migration 0019); without a row the check's estimate counts."""

    __tablename__ = "standard_times"

    version_id: Mapped[int] = mapped_column(ForeignKey("program_versions.id"), primary_key=True)
    seconds: Mapped[float] = mapped_column(Float)
    set_by: Mapped[str] = mapped_column(String(64))
    set_at: Mapped[datetime] = mapped_column(UtcDateTime(), default=utcnow)


class PartReport(Base):
    """Parts an operator (or a program through the API) reported for a machine: good ones
    and scrapped ones, counted in the period that holds ``at`` (OEE's quality)."""

    __tablename__ = "part_reports"
    __table_args__ = (Index("ix_part_reports_machine_at", "machine", "at"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    machine: Mapped[str] = mapped_column(String(64))
    at: Mapped[datetime] = mapped_column(UtcDateTime(), default=utcnow)
    good: Mapped[int] = mapped_column(Integer, default=0)
    scrap: Mapped[int] = mapped_column(Integer, default=0)
    by: Mapped[str] = mapped_column(String(64))
    note: Mapped[str] = mapped_column(String(200), default="")


class DowntimeReason(Base):
    """Why a machine stopped: the reason an operator picked for the stop that began at
    ``start`` (one per stop: picking again replaces it)."""

    __tablename__ = "downtime_reasons"
    __table_args__ = (
        UniqueConstraint("machine", "start", name="uq_downtime_reasons_machine_start"),
    )

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    machine: Mapped[str] = mapped_column(String(64))
    start: Mapped[datetime] = mapped_column(UtcDateTime())
    reason: Mapped[str] = mapped_column(String(64))
    note: Mapped[str] = mapped_column(String(200), default="")
    by: Mapped[str] = mapped_column(String(64))
    at: Mapped[datetime] = mapped_column(UtcDateTime(), default=utcnow)


class ShiftReportSent(Base):
    """A shift report's e-mail claimed by one server before it is sent (migration 0021).

    The row is the claim: the server whose insert goes through sends the report, any other
    (another server of the cluster, this one after a restart) finds it and does not. ``state``
    is ``sending`` until the SMTP server answered, then ``sent`` or ``failed``; a server killed
    in between leaves ``sending``, and that report is not sent again (a second copy is worse
    than a missing one the audit trail shows: docs/dashboard.md#shift-report)."""

    __tablename__ = "shift_reports"

    shift: Mapped[str] = mapped_column(String(64), primary_key=True)  # "2026-01-05 early"
    state: Mapped[str] = mapped_column(String(16), default="sending")
    server: Mapped[str] = mapped_column(String(64), default="")
    claimed: Mapped[datetime] = mapped_column(UtcDateTime(), default=utcnow)
    finished: Mapped[datetime | None] = mapped_column(UtcDateTime(), nullable=True)
    error: Mapped[str] = mapped_column(Text, default="")
