"""The library's program check: the dry run of a version (:mod:`opendnc.nccheck`), bounded,
and kept in ``version_checks`` so a page, a release and a send read it instead of running it
again (docs/server.md#program-checks).

A check runs in the caller's thread (the routes that reach it run in FastAPI's thread pool,
never on the event loop), at most :data:`PARALLEL` at a time in this process, within the
checker's block and CPU-time budget; a program larger than :data:`CHECK_BYTES` is not run
and its result is an error saying so (it blocks a release or a send until overridden). Checks
against a machine are kept by a digest of the machine's limits, not by its name, so the
machines of one kind and envelope share one row and a changed ``travel`` makes a new one.
"""

from __future__ import annotations

import hashlib
import json
import threading
from dataclasses import dataclass
from typing import Any

from sqlalchemy import func, select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session, sessionmaker

from opendnc.nccheck import Budget, CheckResult, Library, MachineLimits, check_text
from opendnc.nccheck.oversize import MAX_PROGRAM_BYTES, not_checked
from opendnc.server.store.models import Program, ProgramState, ProgramVersion, VersionCheck

__all__ = [
    "CHECK_BYTES",
    "MAX_STORED_PROBLEMS",
    "PARALLEL",
    "Checked",
    "Library",
    "check_saved",
    "limits_key",
    "load",
    "problems_of",
    "run",
    "store",
    "summary_of",
]

CHECK_BYTES = MAX_PROGRAM_BYTES
"""A larger program is not dry-run (a drip-fed mould program can be hundreds of MB; the
checker's budget would stop part way anyway): its check is one error saying so, never a pass."""
PARALLEL = 2
"""Dry runs at once in this process (each takes a core for up to its budget)."""
BUDGET = Budget(seconds=5.0, moves=0)  # the server keeps no moves: the preview runs its own
MAX_STORED_PROBLEMS = 500  # a file of garbage has a problem a line; the counts stay exact
_SLOTS = threading.BoundedSemaphore(PARALLEL)
# Extensions a called program is looked up with when the call names a bare number (O09010).
_CALLED_SUFFIXES = ("", ".nc", ".NC", ".txt", ".TXT", ".H", ".h", ".I", ".i")


@dataclass(frozen=True)
class Checked:
    """A stored check, as the actions read it."""

    version_id: int
    limits: str
    control: str
    errors: int
    warnings: int
    summary: str
    problems: list[dict[str, Any]]
    facts: dict[str, Any]
    checked: Any

    @classmethod
    def of(cls, row: VersionCheck) -> Checked:
        """From the row."""
        return cls(
            version_id=row.version_id,
            limits=row.limits,
            control=row.control,
            errors=row.errors,
            warnings=row.warnings,
            summary=row.summary,
            problems=list(row.problems),
            facts=dict(row.facts),
            checked=row.checked,
        )

    @property
    def ok(self) -> bool:
        """No error (warnings allowed)."""
        return self.errors == 0

    def first_error(self) -> dict[str, Any] | None:
        """The first error's problem, if there is one."""
        return next((p for p in self.problems if p.get("severity") == "error"), None)


def limits_key(limits: MachineLimits | None) -> str:
    """``""`` for the check of the text alone, else a digest of what the check of a machine
    depends on (not its name: machines alike share one check)."""
    if limits is None:
        return ""
    shape = {
        "family": limits.family,
        "travel": sorted((axis, list(pair)) for axis, pair in limits.travel.items()),
        "units": limits.travel_units.value if limits.travel_units else None,
        "offsets": sorted(
            (name, sorted(axes.items())) for name, axes in limits.work_offsets.items()
        ),
        "tools": sorted(limits.tools) if limits.tools is not None else None,
        "protected": [list(r) for r in limits.protected],
        "rapid": limits.rapid_rate,
        "dialect": limits.dialect,
    }
    text = json.dumps(shape, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


def anonymous(limits: MachineLimits) -> MachineLimits:
    """``limits`` without the machine's name (the stored check is shared by its key)."""
    return MachineLimits(
        name="",
        family=limits.family,
        travel=limits.travel,
        travel_units=limits.travel_units,
        work_offsets=limits.work_offsets,
        tools=limits.tools,
        protected=limits.protected,
        rapid_rate=limits.rapid_rate,
        dialect=limits.dialect,
    )


def run(
    name: str,
    data: bytes,
    limits: MachineLimits | None,
    library: Library | None = None,
) -> CheckResult:
    """The dry run of ``data`` (bounded: see the module's text). Never raises on content."""
    if len(data) > CHECK_BYTES:
        from opendnc.nccheck import guess_control

        text_head = data[:4096].decode("latin-1")
        return not_checked(name, len(data), guess_control(text_head, name))
    text = data.decode("latin-1")  # NC programs are 7-bit text; latin-1 keeps every byte
    with _SLOTS:
        return check_text(
            text,
            name=name,
            machine=anonymous(limits) if limits is not None else None,
            library=library,
            budget=BUDGET,
        )


def summary_of(result: CheckResult) -> str:
    """The one line a page shows of ``result``: counts, control, tools, estimated time."""
    errors, warnings = len(result.errors), len(result.warnings)
    minutes, seconds = divmod(round(result.cycle_time_s), 60)
    tools = len(result.tools)
    return (
        f"{errors} error{'s' * (errors != 1)}, {warnings} warning{'s' * (warnings != 1)}; "
        f"{result.control.value}, {tools} tool{'s' * (tools != 1)}, "
        f"about {minutes}:{seconds:02d} min"
    )


def store(session: Session, version_id: int, key: str, result: CheckResult) -> Checked:
    """Keep ``result`` as the check of version ``version_id`` under ``key`` (another
    request that stored it first wins: both ran the same check)."""
    found = load(session, version_id, key)
    if found is not None:
        return found
    facts = result.to_dict()
    for dropped in ("moves", "problems", "name", "ok", "control"):
        facts.pop(dropped, None)
    row = VersionCheck(
        version_id=version_id,
        limits=key,
        control=result.control.value,
        errors=len(result.errors),
        warnings=len(result.warnings),
        summary=summary_of(result),
        problems=problems_of(result),
        facts=facts,
    )
    try:
        with session.begin_nested():  # a savepoint: losing the race to store it is no error
            session.add(row)
    except IntegrityError:
        found = load(session, version_id, key)
        assert found is not None
        return found
    return Checked.of(row)


def problems_of(result: CheckResult) -> list[dict[str, Any]]:
    """The first :data:`MAX_STORED_PROBLEMS` problems of ``result`` as stored and shown."""
    return [
        {
            "line": p.line,
            "block": p.block,
            "severity": p.severity.value,
            "message": p.message,
        }
        for p in result.problems[:MAX_STORED_PROBLEMS]
    ]


def load(session: Session, version_id: int, key: str) -> Checked | None:
    """The stored check of version ``version_id`` under ``key``, if there is one."""
    row = session.scalar(
        select(VersionCheck).where(
            VersionCheck.version_id == version_id, VersionCheck.limits == key
        )
    )
    return Checked.of(row) if row is not None else None


def called_program(session: Session, called: str) -> bytes | None:
    """The bytes a program call (``O09010``, ``SUB.H``) finds in the library: the released
    version of the program of that name (any case, with or without a usual extension),
    else its newest; None when there is none."""
    base = called.rsplit("/", 1)[-1].rsplit("\\", 1)[-1].rsplit(":", 1)[-1]
    names = {(base + suffix).lower() for suffix in _CALLED_SUFFIXES}
    program = session.scalar(
        select(Program).where(func.lower(Program.name).in_(names)).order_by(Program.name).limit(1)
    )
    if program is None:
        return None
    versions = session.scalars(
        select(ProgramVersion)
        .where(ProgramVersion.program_id == program.id)
        .order_by(ProgramVersion.number.desc())
    ).all()
    if not versions:
        return None
    chosen = next((v for v in versions if v.state is ProgramState.RELEASED), versions[0])
    from opendnc.server.store.models import Blob

    blob = session.get(Blob, chosen.sha256)
    return blob.data if blob is not None else None


def library_lookup(reads: sessionmaker[Session]) -> Library:
    """The checker's ``library`` callback on the database: a called program's text."""

    def find(called: str) -> str | None:
        with reads() as session:
            data = called_program(session, called)
        return data.decode("latin-1") if data is not None else None

    return find


def check_saved(
    sessions: sessionmaker[Session], version_id: int, name: str, data: bytes
) -> Checked:
    """Check a version just saved (committed) by the text alone and keep the result, in a
    transaction of its own after the dry run (the folder watcher's and the inbox's saves)."""
    result = run(name, data, None, library_lookup(sessions))
    with sessions.begin() as session:
        return store(session, version_id, "", result)
