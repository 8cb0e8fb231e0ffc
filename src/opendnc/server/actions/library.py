"""Library actions: list and read programs, upload a version (a draft), release, lock."""

from __future__ import annotations

import hashlib

from sqlalchemy.orm import Session

from opendnc.errors import InputError
from opendnc.server import library
from opendnc.server.actions.base import Caller, Services, require
from opendnc.server.actions.models import (
    Content,
    DiffOut,
    ProgramOut,
    TextMatch,
    UploadOut,
    VersionOut,
)
from opendnc.server.program_title import HEAD, title_of
from opendnc.server.store.models import Program, Role

__all__ = [
    "get_program",
    "list_programs",
    "may_upload",
    "program_content",
    "program_diff",
    "release_version",
    "set_locked",
    "upload_program",
]

MAX_SEARCH = 100  # a name is at most 100 characters: a longer search finds nothing
MIN_TEXT = 2  # a search in the text of one character would list most of the library


def list_programs(svc: Services, who: Caller, search: str = "", text: str = "") -> list[ProgramOut]:
    """Programs whose name or title holds ``search`` (any case), and whose newest version's
    text holds ``text`` (any case; at most :data:`~opendnc.server.library.MAX_TEXT_HITS`),
    by name, each with its title."""
    require(who, Role.VIEWER)
    search, text = search.strip(), text.strip()
    if len(search) > library.MAX_SEARCH or len(text) > library.MAX_SEARCH:
        raise InputError(f"a search is at most {library.MAX_SEARCH} characters")
    if text and len(text) < MIN_TEXT:
        raise InputError(f"a search in the text needs at least {MIN_TEXT} characters")

    def load(session: Session) -> list[ProgramOut]:
        found: list[tuple[Program, TextMatch | None]]
        if text:
            hits = library.search_text(session, text)
            found = [(h.program, TextMatch(line=h.line, text=h.text)) for h in hits]
        else:
            found = [(p, None) for p in library.list_programs(session)]
        newest = [p.versions[-1].sha256 for p, _ in found if p.versions]
        heads = library.heads(session, newest, HEAD)
        out = []
        for program, match in found:
            title = (
                title_of(heads.get(program.versions[-1].sha256, b"")) if program.versions else ""
            )
            if search and search.lower() not in f"{program.name}\n{title}".lower():
                continue
            out.append(ProgramOut.of(program).model_copy(update={"title": title, "match": match}))
        return out

    return svc.read(load)


def get_program(svc: Services, who: Caller, name: str) -> ProgramOut:
    """One program and its versions."""
    require(who, Role.VIEWER)
    library.check_program_name(name)
    return svc.read(lambda s: ProgramOut.of(library.get_program(s, name)))


def program_content(svc: Services, who: Caller, name: str, number: int | None) -> Content:
    """The bytes of version ``number`` of ``name`` (the newest without it)."""
    require(who, Role.VIEWER)
    library.check_program_name(name)

    def load(session: Session) -> Content:
        version = library.get_version(session, name, number)
        return Content(name, version.sha256, library.content(session, version))

    return svc.read(load)


def program_diff(svc: Services, who: Caller, name: str, a: int, b: int) -> DiffOut:
    """A unified diff from version ``a`` to version ``b``."""
    require(who, Role.VIEWER)
    library.check_program_name(name)
    return svc.read(lambda s: DiffOut(program=name, a=a, b=b, lines=library.diff(s, name, a, b)))


def may_upload(who: Caller) -> None:
    """Refuse a caller who may not add versions, before an upload's body is read."""
    require(who, Role.PROGRAMMER)


def upload_program(
    svc: Services,
    who: Caller,
    name: str,
    data: bytes,
    *,
    comment: str = "",
    sha256: str | None = None,
) -> UploadOut:
    """Store ``data`` as the next version of ``name``: a draft, until an approver releases
    it. ``sha256`` (the client's, optional) must match the bytes."""
    may_upload(who)
    library.check_program_name(name)
    if not data:
        raise InputError("the upload is empty")
    if sha256 and hashlib.sha256(data).hexdigest() != sha256.strip().lower():
        raise InputError("the upload does not match its X-Content-SHA256 header")

    def store(session: Session) -> UploadOut:
        version, created = library.add_version(
            session, name, data, author=who.name, comment=comment
        )
        return UploadOut(**VersionOut.of(version).model_dump(), created_new=created)

    out = svc.write(store)
    svc.changed("program", name)
    return out


def release_version(svc: Services, who: Caller, name: str, number: int) -> VersionOut:
    """Release a version (the one released before becomes superseded)."""
    require(who, Role.APPROVER)
    library.check_program_name(name)
    out = svc.write(lambda s: VersionOut.of(library.release(s, name, number, actor=who.name)))
    svc.changed("program", name)
    return out


def set_locked(svc: Services, who: Caller, name: str, locked: bool) -> ProgramOut:
    """Lock a program against new versions and state changes, or unlock it."""
    require(who, Role.APPROVER)
    library.check_program_name(name)
    out = svc.write(lambda s: ProgramOut.of(library.set_locked(s, name, locked, actor=who.name)))
    svc.changed("program", name)
    return out
