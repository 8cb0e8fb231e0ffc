"""The program library: versions addressed by SHA-256, approval states, diffs.

Every change a person or the folder watcher makes becomes a new version; nothing is overwritten.
Adding the bytes the newest version already has adds nothing (the watcher sees the same file
many times). States: a new version is a draft; releasing it supersedes the version released
before; a locked program takes no new versions and no state changes until it is unlocked.
"""

from __future__ import annotations

import difflib
import hashlib
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from datetime import datetime
from typing import NamedTuple

from sqlalchemy import ColumnElement, Select, String, cast, func, literal, select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session, joinedload, selectinload

from opendnc.errors import InputError
from opendnc.server.core.errors import Conflict, NotFound
from opendnc.server.store import audit
from opendnc.server.store.models import Blob, Program, ProgramState, ProgramVersion
from opendnc.server.store.notify import Topic, notify

__all__ = [
    "MAX_PROGRAM_BYTES",
    "MAX_SEARCH",
    "MAX_TEXT_HITS",
    "History",
    "Listed",
    "TextHit",
    "VersionRow",
    "add_version",
    "check_program_name",
    "content",
    "diff",
    "get_program",
    "get_version",
    "heads",
    "history",
    "list_programs",
    "release",
    "released_names",
    "same_name_but_case",
    "search_text",
    "set_locked",
]

# Larger than any program a control's memory takes; a drip-fed mould program can be tens of MB.
MAX_PROGRAM_BYTES = 256 * 1024 * 1024
MAX_SEARCH = 255  # the API's bound on a search (a name is at most 100 characters)

# One file name, as controls and shares accept it: no folders, no dot-names, no Windows
# device names, nothing a path join could turn into a different place.
_PROGRAM_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.+$-]{0,99}$")
_WINDOWS_DEVICES = {
    "CON",
    "PRN",
    "AUX",
    "NUL",
    *(f"COM{i}" for i in range(10)),
    *(f"LPT{i}" for i in range(10)),
}


# A program's versions, each with its program set (relationships never load lazily; within
# a transaction SQLAlchemy does not take a version's program from the identity map).
_VERSIONS = selectinload(Program.versions).joinedload(ProgramVersion.program)


def check_program_name(name: str) -> str:
    """``name`` if it is a safe program file name; :class:`InputError` saying why not."""
    if not _PROGRAM_NAME.fullmatch(name) or ".." in name:
        raise InputError(
            f"program name {name[:40]!r}: use 1-100 letters, digits, '.', '_', '+', '$' or '-', "
            "starting with a letter or digit, no folders"
        )
    if name.split(".")[0].upper() in _WINDOWS_DEVICES:
        raise InputError(f"program name {name!r} is a reserved device name on Windows")
    if name.endswith("."):
        # Windows and SMB shares drop a trailing dot: 'O1.nc.' would be the file 'O1.nc'.
        raise InputError(
            f"program name {name!r} ends in '.', which Windows drops: call it {name.rstrip('.')!r}"
        )
    return name


def same_name_but_case(session: Session, name: str) -> str | None:
    """The existing program whose name differs from ``name`` only in case, if there is one.

    Windows, SMB shares and macOS fold case: 'o1.nc' and 'O1.NC' there are one file, so the
    library holds at most one of them (docs/server.md#program-names).
    """
    stmt = select(Program.name).where(
        func.lower(Program.name) == name.lower(), Program.name != name
    )
    return session.scalars(stmt).first()


@dataclass(frozen=True)
class Listed:
    """A program as the library's list shows it: how many versions, the newest, the released."""

    program: Program
    count: int
    newest: ProgramVersion | None
    released: ProgramVersion | None

    @property
    def name(self) -> str:
        """The program's name."""
        return self.program.name


def list_programs(
    session: Session, search: str = "", names: Sequence[str] | None = None
) -> list[Listed]:
    """Programs whose name contains ``search`` (case-insensitive), by name.

    Each with its newest and its released version only: the list's cost does not grow with
    the versions a program has had (:func:`get_program` has them all). ``search`` longer
    than a name can be (:data:`MAX_SEARCH`) is an :class:`InputError`: it could match
    nothing, and SQLite refuses a LIKE pattern of 50,000 characters and more. ``%`` and
    ``_`` in it match themselves. ``names`` lists only these (those a search in the text
    found)."""
    if len(search) > MAX_SEARCH:
        raise InputError(f"a search is at most {MAX_SEARCH} characters (a name's length)")
    where = [func.lower(Program.name).contains(search.lower(), autoescape=True)] if search else []
    if names is not None:
        where.append(Program.name.in_(list(names)))
    per_program = (
        select(
            ProgramVersion.program_id,
            func.max(ProgramVersion.number).label("newest"),
            func.count().label("count"),
        )
        .group_by(ProgramVersion.program_id)
        .subquery()
    )
    programs = session.execute(
        select(Program, per_program.c.count, per_program.c.newest)
        .outerjoin(per_program, per_program.c.program_id == Program.id)
        .where(*where)
        .order_by(Program.name)
    ).all()
    if not programs:
        return []
    # The newest and the released version of each listed program, in one query.
    picked = session.scalars(
        select(ProgramVersion)
        .join(Program, Program.id == ProgramVersion.program_id)
        .outerjoin(
            per_program,
            (per_program.c.program_id == ProgramVersion.program_id)
            & (per_program.c.newest == ProgramVersion.number),
        )
        .where(
            *where,
            (ProgramVersion.state == ProgramState.RELEASED) | per_program.c.newest.is_not(None),
        )
        .options(joinedload(ProgramVersion.program))
    ).all()
    newest: dict[int, ProgramVersion] = {}
    released: dict[int, ProgramVersion] = {}
    for version in picked:
        if version.state is ProgramState.RELEASED:
            released[version.program_id] = version
        known = newest.get(version.program_id)
        if known is None or version.number > known.number:
            newest[version.program_id] = version
    return [
        Listed(program, count or 0, newest.get(program.id), released.get(program.id))
        for program, count, _newest in programs
    ]


def get_program(session: Session, name: str) -> Program:
    """The program called ``name``; :class:`NotFound` otherwise."""
    program = session.scalar(_with_versions(name))
    if program is None:
        raise NotFound(f"no program named {name!r}")
    return program


class VersionRow(NamedTuple):
    """A version as a list shows it, read as plain columns (no ORM object per version)."""

    number: int
    sha256: str
    size: int
    state: ProgramState
    author: str
    comment: str
    source: str
    created: datetime


@dataclass(frozen=True)
class History:
    """A program, how many versions it has, and its newest ones (oldest first)."""

    program: Program
    count: int
    versions: list[VersionRow]


def history(session: Session, name: str, limit: int | None = None) -> History:
    """``name`` with its newest ``limit`` versions (all without a limit); :class:`NotFound`
    otherwise. Versions are read as columns: a long history costs what its rows cost."""
    program = session.scalar(select(Program).where(Program.name == name))
    if program is None:
        raise NotFound(f"no program named {name!r}")
    v = ProgramVersion
    stmt = (
        select(v.number, v.sha256, v.size, v.state, v.author, v.comment, v.source, v.created)
        .where(v.program_id == program.id)
        .order_by(v.number.desc())
    )
    if limit is not None:
        stmt = stmt.limit(limit)
    rows = [VersionRow(*row) for row in session.execute(stmt)]
    rows.reverse()
    count = len(rows)
    if limit is not None and count >= limit:
        count = session.scalar(select(func.count()).where(v.program_id == program.id)) or 0
    return History(program, count, rows)


def _with_versions(name: str) -> Select[Program]:
    # the program and its versions in two queries (relationships never load lazily)
    return select(Program).where(Program.name == name).options(_VERSIONS)


def get_version(session: Session, name: str, number: int | None = None) -> ProgramVersion:
    """Version ``number`` of ``name``; the newest one when ``number`` is None.

    One indexed look-up, whatever the number of versions the program has."""
    stmt = _versions_of(name)
    if number is None:
        stmt = stmt.order_by(ProgramVersion.number.desc()).limit(1)
    else:
        stmt = stmt.where(ProgramVersion.number == number)
    version = session.scalar(stmt)
    if version is not None:
        return version
    if session.scalar(select(Program.id).where(Program.name == name)) is None:
        raise NotFound(f"no program named {name!r}")
    if number is None:
        raise NotFound(f"program {name!r} has no versions")
    raise NotFound(f"program {name!r} has no version {number}")


def released_names(session: Session, limit: int = 2000) -> list[str]:
    """The names of the programs with a released version, in order (at most ``limit``)."""
    stmt = (
        select(Program.name)
        .join(ProgramVersion)
        .where(ProgramVersion.state == ProgramState.RELEASED)
        .distinct()
        .order_by(Program.name)
        .limit(limit)
    )
    return list(session.scalars(stmt))


def released_version(session: Session, name: str) -> ProgramVersion | None:
    """The released version of ``name``, if one is (:class:`NotFound` without the program)."""
    version = session.scalar(
        _versions_of(name)
        .where(ProgramVersion.state == ProgramState.RELEASED)
        .order_by(ProgramVersion.number.desc())
        .limit(1)
    )
    if version is None and session.scalar(select(Program.id).where(Program.name == name)) is None:
        raise NotFound(f"no program named {name!r}")
    return version


def _versions_of(name: str) -> Select[ProgramVersion]:
    # each with its program set (relationships never load lazily)
    return (
        select(ProgramVersion)
        .join(Program, Program.id == ProgramVersion.program_id)
        .where(Program.name == name)
        .options(joinedload(ProgramVersion.program))
    )


def content(session: Session, version: ProgramVersion) -> bytes:
    """The bytes of ``version``."""
    blob = session.get(Blob, version.sha256)
    if blob is None:  # pragma: no cover - the foreign key makes this impossible
        raise NotFound(f"content {version.sha256} is missing")
    return blob.data


def add_version(
    session: Session,
    name: str,
    data: bytes,
    *,
    author: str,
    comment: str = "",
    source: str = "upload",
) -> tuple[ProgramVersion, bool]:
    """Store ``data`` as the next version of ``name``; returns (version, created).

    ``created`` is False when the newest version already holds exactly these bytes.
    """
    check_program_name(name)
    if len(data) > MAX_PROGRAM_BYTES:
        raise InputError(f"{name}: {len(data)} bytes is more than the library takes")
    digest = hashlib.sha256(data).hexdigest()
    program = _program_for_update(session, name)
    if program.locked:
        raise Conflict(f"program {name!r} is locked")
    # Only the newest version is read: an upload's cost does not grow with the history.
    newest = session.scalar(
        select(ProgramVersion)
        .where(ProgramVersion.program_id == program.id)
        .order_by(ProgramVersion.number.desc())
        .limit(1)
        .options(joinedload(ProgramVersion.program))
    )
    if newest is not None and newest.sha256 == digest:
        return newest, False
    if session.get(Blob, digest) is None:
        session.add(Blob(sha256=digest, size=len(data), data=data))
    version = ProgramVersion(
        program_id=program.id,
        number=newest.number + 1 if newest is not None else 1,
        sha256=digest,
        size=len(data),
        state=ProgramState.DRAFT,
        author=author,
        comment=comment,
        source=source,
    )
    version.program = program
    session.add(version)
    session.flush()
    audit.record(
        session,
        author,
        "program.version",
        program=name,
        sha256=digest,
        nbytes=len(data),
        version=version.number,
        source=source,
        comment=comment,
    )
    # the other servers' pages and streams
    notify(session, Topic.LIBRARY, f"{version.number}:{name}")
    return version, True


def _program_for_update(session: Session, name: str) -> Program:
    # Two uploads of one name at the same moment must not both number their version N+1. On
    # PostgreSQL the program's row is locked until the commit (SQLite has no row locks and
    # needs none: a writing transaction there holds the database's write lock throughout).
    stmt = select(Program).where(Program.name == name).with_for_update()
    program = session.scalar(stmt)
    if program is not None:
        return program
    _refuse_case_twin(session, name)
    try:
        with session.begin_nested():  # a savepoint: losing the race to create it is not an error
            session.add(Program(name=name))
    except IntegrityError:
        # Another upload created it (or a name that differs only in case: the unique index on
        # the folded name refuses the second of two at the same moment, which the check above
        # cannot see on PostgreSQL while the first is not committed).
        pass
    program = session.scalar(stmt)
    if program is None:
        _refuse_case_twin(session, name)
        raise Conflict(f"program {name!r} could not be created; try again")  # pragma: no cover
    return program


def _refuse_case_twin(session: Session, name: str) -> None:
    other = same_name_but_case(session, name)
    if other is not None:
        raise Conflict(
            f"program {name!r} differs from {other!r} only in case, and file systems that "
            f"fold case (Windows, network shares) would make them one file: use {other!r}"
        )


def release(session: Session, name: str, number: int, *, actor: str) -> ProgramVersion:
    """Release version ``number``; the previously released version becomes superseded."""
    program = get_program(session, name)
    if program.locked:
        raise Conflict(f"program {name!r} is locked")
    target = get_version(session, name, number)
    if target.state is ProgramState.RELEASED:
        return target
    if target.state is ProgramState.SUPERSEDED:
        raise Conflict(f"{name} version {number} is superseded; release a newer one")
    for version in program.versions:
        if version.state is ProgramState.RELEASED:
            version.state = ProgramState.SUPERSEDED
    target.state = ProgramState.RELEASED
    audit.record(
        session, actor, "program.release", program=name, sha256=target.sha256, version=number
    )
    notify(session, Topic.LIBRARY, f"{number}:{name}")
    return target


def set_locked(session: Session, name: str, locked: bool, *, actor: str) -> Program:
    """Lock or unlock ``name``."""
    program = get_program(session, name)
    if program.locked != locked:
        program.locked = locked
        audit.record(session, actor, "program.lock" if locked else "program.unlock", program=name)
    return program


def diff(session: Session, name: str, a: int, b: int, *, context: int = 3) -> list[str]:
    """Unified diff lines from version ``a`` to version ``b`` of ``name``."""
    old = get_version(session, name, a)
    new = get_version(session, name, b)
    # G-code is ASCII; latin-1 shows any stray byte instead of failing on it.
    old_lines = content(session, old).decode("latin-1").splitlines()
    new_lines = content(session, new).decode("latin-1").splitlines()
    return list(
        difflib.unified_diff(
            old_lines, new_lines, f"{name} v{a}", f"{name} v{b}", n=context, lineterm=""
        )
    )


MAX_TEXT_HITS = 100  # programs a search in the text lists at most


@dataclass(frozen=True)
class TextHit:
    """A program whose newest version holds the searched text, and its first line that does."""

    name: str
    line: int
    text: str


def heads(session: Session, digests: Iterable[str], size: int) -> dict[str, bytes]:
    """The first ``size`` bytes of each content of ``digests`` (read in the database, not
    whole): what a list needs to name each program's title."""
    wanted = sorted(set(digests))
    out: dict[str, bytes] = {}
    for i in range(0, len(wanted), 500):
        rows = session.execute(
            select(Blob.sha256, func.substr(Blob.data, 1, size)).where(
                Blob.sha256.in_(wanted[i : i + 500])
            )
        )
        out.update({digest: bytes(head or b"") for digest, head in rows})
    return out


def _escape_like(text: str) -> str:
    return text.replace("\\", "\\\\").replace("%", "\\%").replace("_", "\\_")


def search_text(session: Session, text: str, limit: int = MAX_TEXT_HITS) -> list[TextHit]:
    """Programs whose newest version contains ``text`` (any case, ASCII), by name, at most
    ``limit``; each with its first line that does. ``%``, ``_`` and ``\\`` match
    themselves. The database looks through the contents (LIKE), this only through the
    programs it found."""
    if not text:
        return []
    if len(text) > MAX_SEARCH:
        raise InputError(f"a search is at most {MAX_SEARCH} characters")
    newest = (
        select(ProgramVersion.program_id, func.max(ProgramVersion.number).label("number"))
        .group_by(ProgramVersion.program_id)
        .subquery()
    )
    haystack: ColumnElement[str]
    if session.get_bind().dialect.name == "postgresql":
        # bytea as text: encode(..., 'escape') keeps ASCII and doubles backslashes
        haystack = func.encode(Blob.data, literal("escape"))
        needle = text.replace("\\", "\\\\")
        found = haystack.ilike(f"%{_escape_like(needle)}%", escape="\\")
    else:
        # SQLite: the bytes as text; its LIKE ignores ASCII case
        haystack = cast(Blob.data, String)
        found = haystack.like(f"%{_escape_like(text)}%", escape="\\")
    rows = session.execute(
        select(Program.name, ProgramVersion.sha256)
        .join(newest, newest.c.program_id == Program.id)
        .join(
            ProgramVersion,
            (ProgramVersion.program_id == Program.id) & (ProgramVersion.number == newest.c.number),
        )
        .join(Blob, Blob.sha256 == ProgramVersion.sha256)
        .where(found)
        .order_by(Program.name)
        .limit(limit)
    ).all()
    hits = []
    wanted = text.lower()
    for name, digest in rows:
        blob = session.get(Blob, digest)
        data = blob.data.decode("latin-1") if blob is not None else ""
        for number, line in enumerate(data.splitlines(), 1):
            if wanted in line.lower():
                hits.append(TextHit(name, number, line.strip()[:200]))
                break
    return hits
