"""Library actions: list and read programs, upload or edit a version (a draft, checked on
save), release (its program check must pass, or a programmer overrides it), lock."""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from typing import TypeVar

from sqlalchemy.orm import Session

from opendnc.errors import InputError
from opendnc.server.actions import checks, policy
from opendnc.server.actions.base import Caller, Services, require
from opendnc.server.actions.models import (
    Content,
    DiffOut,
    ProgramListed,
    ProgramOut,
    Stored,
    TextMatch,
    UploadOut,
    VersionOut,
)
from opendnc.server.core.events import ProgramChanged
from opendnc.server.library import versions as library
from opendnc.server.library.titles import HEAD, title_of
from opendnc.server.store.models import Role

__all__ = [
    "get_program",
    "list_programs",
    "may_upload",
    "program_content",
    "program_diff",
    "release_version",
    "released_names",
    "save_edit",
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
    text holds ``text`` (any case; at most :data:`~opendnc.server.library.versions.MAX_TEXT_HITS`),
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


def program_stored(svc: Services, who: Caller, name: str, number: int | None) -> Stored:
    """Where the bytes of version ``number`` of ``name`` (the newest without it) are kept,
    for a download that streams them."""
    require(who, Role.VIEWER)
    library.check_program_name(name)

    def load(session: Session) -> Stored:
        version = library.get_version(session, name, number)
        return Stored(name, version.sha256, version.size)

    return svc.read(load)


def program_diff(svc: Services, who: Caller, name: str, a: int, b: int) -> DiffOut:
    """A unified diff from version ``a`` to version ``b``."""
    require(who, Role.VIEWER)
    library.check_program_name(name)
    return svc.read(lambda s: DiffOut(program=name, a=a, b=b, lines=library.diff(s, name, a, b)))


def released_names(svc: Services, who: Caller) -> list[str]:
    """The programs with a released version, by name (what a drip-feed machine is offered;
    viewers)."""
    require(who, Role.VIEWER)
    return svc.read(library.released_names)


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

    return _store(svc, who, name, data, comment, "upload")


def _store(
    svc: Services, who: Caller, name: str, data: bytes, comment: str, source: str
) -> UploadOut:
    def store(session: Session) -> tuple[UploadOut, checks.Target]:
        version, created = library.add_version(
            session, name, data, author=who.name, comment=comment, source=source
        )
        out = UploadOut(**VersionOut.of(version).model_dump(), created_new=created)
        return out, checks.Target.of(version)

    out, target = _change(svc, name, store)
    # checked on save, after the commit (the dry run holds no write lock)
    out.check = checks.check_out(target, checks.ensure(svc, target, None), None)
    return out


def save_edit(
    svc: Services, who: Caller, name: str, base: int, text: str, *, comment: str
) -> UploadOut:
    """Store ``text``, edited in the browser from version ``base``, as the next version of
    ``name`` (a draft; programmers), with the ``comment`` that says why; it is checked on
    save. The line ends of ``base`` are kept (a browser sends CR LF whatever it was given)."""
    may_upload(who)
    library.check_program_name(name)
    why = comment.strip()
    if not why:
        raise InputError("an edit needs a comment saying what changed")
    old = program_content(svc, who, name, base).data
    text = text.replace("\r\n", "\n").replace("\r", "\n")
    if b"\r\n" in old:
        text = text.replace("\n", "\r\n")
    try:
        data = text.encode("latin-1")
    except UnicodeEncodeError as exc:
        line = text.count("\n", 0, exc.start) + 1
        raise InputError(f"line {line}: {text[exc.start]!r} is not NC program text") from None
    if not data:
        raise InputError("the edited program is empty")
    return _store(svc, who, name, data, why, "editor")


def release_version(
    svc: Services, who: Caller, name: str, number: int, override: str | None = None
) -> VersionOut:
    """Release a version (the one released before becomes superseded). Its program check
    must find no error, unless ``override`` gives a reason (programmers; audited)."""
    # the role, the name, the override and the check of the text, before the transaction
    prepared = policy.authorize(
        svc, who, policy.Wanted(name, number), [], policy.Action.release(), override=override
    )

    def release(session: Session) -> VersionOut:
        decision = prepared.confirm(session)
        decision.require_all()
        for verdict in decision.verdicts:
            policy.record_override(session, decision, verdict)
        return VersionOut.of(library.release(session, name, number, actor=who.name))

    return _change(svc, name, release)


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
    svc.changed(ProgramChanged(name))
    return out
