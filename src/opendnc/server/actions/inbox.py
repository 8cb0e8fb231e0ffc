"""Inbox actions: what the controls sent, compared with the library, accepted or dropped."""

from __future__ import annotations

from collections.abc import Sequence

from sqlalchemy.orm import Session

from opendnc.server.actions import checks
from opendnc.server.actions.base import Caller, Services, require
from opendnc.server.actions.models import (
    Content,
    ReceivedDetail,
    ReceivedOut,
    Stored,
    VersionOut,
)
from opendnc.server.core.events import InboxChanged, ProgramChanged
from opendnc.server.library import inbox
from opendnc.server.library import versions as library
from opendnc.server.store.models import ReceivedState, Role

__all__ = [
    "accept_received",
    "discard_received",
    "get_received",
    "list_received",
    "received_content",
]


def list_received(
    svc: Services, who: Caller, states: Sequence[ReceivedState], limit: int = 200
) -> list[ReceivedOut]:
    """Receptions in ``states`` (all states if empty), newest first."""
    require(who, Role.VIEWER)
    return svc.read(lambda s: [ReceivedOut.of(r) for r in inbox.list_received(s, states, limit)])


def get_received(svc: Services, who: Caller, received_id: int) -> ReceivedDetail:
    """One reception, with the library version of its name and the diff from it."""
    require(who, Role.VIEWER)

    def load(session: Session) -> ReceivedDetail:
        row = inbox.get(session, received_id)
        base = inbox.base_version(session, row.name)
        return ReceivedDetail(
            **ReceivedOut.of(row).model_dump(),
            base=VersionOut.of(base) if base is not None else None,
            diff=inbox.diff_to_library(session, received_id),
        )

    return svc.read(load)


def received_content(svc: Services, who: Caller, received_id: int) -> Content:
    """The received bytes."""
    require(who, Role.VIEWER)

    def load(session: Session) -> Content:
        row = inbox.get(session, received_id)
        return Content(row.name, row.sha256, inbox.content(session, row))

    return svc.read(load)


def received_stored(svc: Services, who: Caller, received_id: int) -> Stored:
    """Where the received bytes are kept, for a download that streams them."""
    require(who, Role.VIEWER)

    def load(session: Session) -> Stored:
        row = inbox.get(session, received_id)
        return Stored(row.name, row.sha256, row.size)

    return svc.read(load)


def base_content(svc: Services, who: Caller, received_id: int) -> bytes:
    """The bytes of the library version a reception is compared with (empty if none)."""
    require(who, Role.VIEWER)

    def load(session: Session) -> bytes:
        base = inbox.base_version(session, inbox.get(session, received_id).name)
        return library.content(session, base) if base is not None else b""

    return svc.read(load)


def accept_received(
    svc: Services, who: Caller, received_id: int, name: str | None = None
) -> VersionOut:
    """Make a reception a new draft version of ``name`` (default: its own name)."""
    require(who, Role.PROGRAMMER)

    def accept(session: Session) -> tuple[VersionOut, checks.Target]:
        version = inbox.accept(session, received_id, actor=who.name, name=name)
        return VersionOut.of(version), checks.Target.of(version)

    out, target = svc.write(accept)
    svc.changed(InboxChanged(str(received_id)))
    svc.changed(ProgramChanged(out.program))
    checks.ensure(svc, target, None)  # checked on save, after the commit
    return out


def discard_received(svc: Services, who: Caller, received_id: int) -> ReceivedOut:
    """Drop a reception from the inbox (its row and file stay for the record)."""
    require(who, Role.PROGRAMMER)
    out = svc.write(lambda s: ReceivedOut.of(inbox.discard(s, received_id, actor=who.name)))
    svc.changed(InboxChanged(str(received_id)))
    return out
