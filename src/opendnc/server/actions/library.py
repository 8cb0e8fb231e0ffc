"""Library actions: list and read programs, upload a version (a draft), release, lock."""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from typing import TypeVar

from sqlalchemy.orm import Session

from opendnc.errors import InputError
from opendnc.server import library
from opendnc.server.actions.base import Caller, Services, require
from opendnc.server.actions.models import (
    Content,
    DiffOut,
    ProgramListed,
    ProgramOut,
    TextMatch,
    UploadOut,
    VersionOut,
)
from opendnc.server.program_title import HEAD, title_of
from opendnc.server.store.models import Role

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

T = TypeVar("T")

MAX_SEARCH = 100  # a name is at most 100 characters: a longer search finds nothing
MIN_TEXT = 2  # a search in the text of one character would list most of the library


def list_programs(
    svc: Services, who: Caller, search: str = "", text: str = ""
) -> list[ProgramListed]:
    """Programs whose name or title holds ``search`` (any case), and whose newest version's
    text holds ``text`` (any case; at most :data:`~opendnc.server.library.MAX_TEXT_HITS`),
    by name: each with its newest and its released version and its title."""
    require(who, Role.VIEWER)
    search, text = search.strip(), text.strip()
    if len(search) > MAX_SEARCH or len(text) > MAX_SEARCH:
        raise InputError(f"a search is at most {MAX_SEARCH} characters")
    if text and len(text) < MIN_TEXT:
        raise InputError(f"a search in the text needs at least {MIN_TEXT} characters")
    if "\x00" in text:  # (PostgreSQL's text holds none: it would be a 500, not a miss)
        raise InputError("a search in the text holds no NUL character")

    def load(session: Session) -> list[ProgramListed]:
        matches: dict[str, TextMatch] = {}
        names = None
        if text:
            hits = library.search_text(session, text)
            matches = {h.name: TextMatch(line=h.line, text=h.text) for h in hits}
            names = list(matches)
        listed = library.list_programs(session, names=names)
        heads = library.heads(session, [x.newest.sha256 for x in listed if x.newest], HEAD)
        out = []
        for item in listed:
            title = title_of(heads.get(item.newest.sha256, b"")) if item.newest else ""
            if search and search.lower() not in f"{item.name}\n{title}".lower():
                continue
            row = ProgramListed.of(item)
            out.append(row.model_copy(update={"title": title, "match": matches.get(item.name)}))
        return out

    return svc.read(load)


def get_program(svc: Services, who: Caller, name: str, limit: int | None = None) -> ProgramOut:
    """One program and its versions: the newest ``limit`` of them, or all."""
    require(who, Role.VIEWER)
    library.check_program_name(name)
    return svc.read(lambda s: ProgramOut.of_history(library.history(s, name, limit)))


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

    return _change(svc, name, store)


def release_version(svc: Services, who: Caller, name: str, number: int) -> VersionOut:
    """Release a version (the one released before becomes superseded)."""
    require(who, Role.APPROVER)
    library.check_program_name(name)
    return _change(
        svc, name, lambda s: VersionOut.of(library.release(s, name, number, actor=who.name))
    )


def set_locked(svc: Services, who: Caller, name: str, locked: bool) -> ProgramOut:
    """Lock a program against new versions and state changes, or unlock it."""
    require(who, Role.APPROVER)
    library.check_program_name(name)
    return _change(
        svc, name, lambda s: ProgramOut.of(library.set_locked(s, name, locked, actor=who.name))
    )


def _change(svc: Services, name: str, change: Callable[[Session], T]) -> T:
    """Run ``change`` in one write transaction, then tell the pages that ``name`` changed."""
    out = svc.write(change)
    svc.changed("program", name)
    return out
