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

from sqlalchemy import ColumnElement, Select, String, cast, func, literal, select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session, selectinload

from opendnc.errors import InputError
from opendnc.server import audit
from opendnc.server.errors import Conflict, NotFound
from opendnc.server.store.models import Blob, Program, ProgramState, ProgramVersion

__all__ = [
    "MAX_PROGRAM_BYTES",
    "MAX_SEARCH",
    "MAX_TEXT_HITS",
    "TextHit",
    "add_version",
    "check_program_name",
    "content",
    "diff",
    "get_program",
    "get_version",
    "heads",
    "list_programs",
    "release",
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


def list_programs(session: Session, search: str = "") -> Sequence[Program]:
    """Programs whose name contains ``search`` (case-insensitive), by name.

    ``search`` longer than a name can be (:data:`MAX_SEARCH`) is an :class:`InputError`: it
    could match nothing, and SQLite refuses a LIKE pattern of 50,000 characters and more.
    ``%`` and ``_`` in it match themselves."""
    if len(search) > MAX_SEARCH:
        raise InputError(f"a search is at most {MAX_SEARCH} characters (a name's length)")
    stmt = select(Program).order_by(Program.name).options(_VERSIONS)
    if search:
        stmt = stmt.where(func.lower(Program.name).contains(search.lower(), autoescape=True))
    return session.scalars(stmt).all()


def get_program(session: Session, name: str) -> Program:
    """The program called ``name``; :class:`NotFound` otherwise."""
    program = session.scalar(_with_versions(name))
    if program is None:
        raise NotFound(f"no program named {name!r}")
    return program


def _with_versions(name: str) -> Select[Program]:
    # the program and its versions in two queries (relationships never load lazily)
    return select(Program).where(Program.name == name).options(_VERSIONS)


def get_version(session: Session, name: str, number: int | None = None) -> ProgramVersion:
    """Version ``number`` of ``name``; the newest one when ``number`` is None."""
    program = get_program(session, name)
    if not program.versions:
        raise NotFound(f"program {name!r} has no versions")
    if number is None:
        return program.versions[-1]
    for version in program.versions:
        if version.number == number:
            return version
    raise NotFound(f"program {name!r} has no version {number}")


def released_version(session: Session, name: str) -> ProgramVersion | None:
    """The released version of ``name``, if one is."""
    program = get_program(session, name)
    for version in reversed(program.versions):
        if version.state is ProgramState.RELEASED:
            return version
    return None


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
    if program.versions and program.versions[-1].sha256 == digest:
        return program.versions[-1], False
    if session.get(Blob, digest) is None:
        session.add(Blob(sha256=digest, size=len(data), data=data))
    number = (program.versions[-1].number + 1) if program.versions else 1
    version = ProgramVersion(
        program=program,
        number=number,
        sha256=digest,
        size=len(data),
        state=ProgramState.DRAFT,
        author=author,
        comment=comment,
        source=source,
    )
    session.add(version)
    session.flush()
    audit.record(
        session,
        author,
        "program.version",
        program=name,
        sha256=digest,
        nbytes=len(data),
        version=number,
        source=source,
        comment=comment,
    )
    return version, True


def _program_for_update(session: Session, name: str) -> Program:
    # Two uploads of one name at the same moment must not both number their version N+1. On
    # PostgreSQL the program's row is locked until the commit (SQLite has no row locks and
    # needs none: a writing transaction there holds the database's write lock throughout).
    stmt = _with_versions(name).with_for_update()
    program = session.scalar(stmt)
    if program is not None:
        return program
    other = same_name_but_case(session, name)
    if other is not None:
        raise Conflict(
            f"program {name!r} differs from {other!r} only in case, and file systems that "
            f"fold case (Windows, network shares) would make them one file: use {other!r}"
        )
    try:
        with session.begin_nested():  # a savepoint: losing the race to create it is not an error
            session.add(Program(name=name, versions=[]))
    except IntegrityError:
        pass
    program = session.scalar(stmt)
    assert program is not None  # created here or by the upload that won the race
    return program


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

    program: Program
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
        select(Program, ProgramVersion.sha256)
        .join(newest, newest.c.program_id == Program.id)
        .join(
            ProgramVersion,
            (ProgramVersion.program_id == Program.id) & (ProgramVersion.number == newest.c.number),
        )
        .join(Blob, Blob.sha256 == ProgramVersion.sha256)
        .where(found)
        .order_by(Program.name)
        .limit(limit)
        .options(_VERSIONS)
    ).all()
    hits = []
    wanted = text.lower()
    for program, digest in rows:
        blob = session.get(Blob, digest)
        data = blob.data.decode("latin-1") if blob is not None else ""
        for number, line in enumerate(data.splitlines(), 1):
            if wanted in line.lower():
                hits.append(TextHit(program, number, line.strip()[:200]))
                break
    return hits
