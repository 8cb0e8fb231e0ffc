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
    UploadOut,
    VersionOut,
)
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


def list_programs(svc: Services, who: Caller, search: str = "") -> list[ProgramListed]:
    """Programs whose name holds ``search`` (any case), by name: each with its newest and
    its released version."""
    require(who, Role.VIEWER)
    search = search.strip()
    if len(search) > MAX_SEARCH:
        return []
    return svc.read(lambda s: [ProgramListed.of(p) for p in library.list_programs(s, search)])


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
