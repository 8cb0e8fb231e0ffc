"""The rules every request to the queue passes: which role each kind of job needs, what a
machine takes (``released_only``, the drip-feed opt-in, the file browser), and what a
version means when none is named. Nothing else in the server decides these."""

from __future__ import annotations

from sqlalchemy.orm import Session

from opendnc.errors import InputError
from opendnc.server import jobs
from opendnc.server.actions.base import Caller, require
from opendnc.server.capabilities import capabilities_of
from opendnc.server.config import MachineConfig
from opendnc.server.errors import Conflict
from opendnc.server.store.models import JobKind, ProgramState, ProgramVersion, Role

__all__ = [
    "JOB_ROLES",
    "TAKE_BACK_ROLE",
    "check_machine",
    "may_queue",
    "may_take_back",
    "version_for",
]

# The least role for each kind of job a person may queue (a report is the server's own).
JOB_ROLES = {
    JobKind.SEND: Role.OPERATOR,
    JobKind.RECEIVE: Role.OPERATOR,
    JobKind.BACKUP: Role.OPERATOR,
    # runs the machine while the program arrives
    JobKind.DRIPFEED: Role.PROGRAMMER,
    # changes files on the control outside the machine's program folder
    JobKind.DELETE: Role.PROGRAMMER,
    JobKind.PUT_FILE: Role.PROGRAMMER,
}


# A control's file taken back into the library becomes a new version of a program: the
# role that adds versions (a receive into the inbox is the operator's).
TAKE_BACK_ROLE = Role.PROGRAMMER


def may_take_back(who: Caller) -> None:
    """Refuse ``who`` taking a control's file back into the library (403) below
    :data:`TAKE_BACK_ROLE`."""
    may_queue(who, JobKind.RECEIVE)
    require(who, TAKE_BACK_ROLE)


def may_queue(who: Caller, kind: JobKind) -> None:
    """Refuse ``who`` a ``kind`` job its role does not allow (403), or one nobody queues."""
    needed = JOB_ROLES.get(kind)
    if needed is None:
        raise InputError(f"{kind.value} jobs are made by the server itself")
    require(who, needed)


def check_machine(
    machine: MachineConfig, kind: JobKind, version: ProgramVersion | None = None
) -> None:
    """Refuse (409) a ``kind`` job of ``version`` that ``machine`` does not take."""
    caps = capabilities_of(machine)
    if kind is JobKind.DRIPFEED and not caps.dripfeed:
        raise Conflict(
            f"{machine.name} does not allow drip-feed (dripfeed = true enables it on a serial Haas)"
        )
    if kind in (JobKind.PUT_FILE,) and not caps.file_browser:
        raise Conflict(f"{machine.name} has no file browser")
    if version is not None and machine.released_only and version.state is not ProgramState.RELEASED:
        raise Conflict(
            f"{machine.name} accepts released programs only; {version.program.name} "
            f"version {version.number} is {version.state.value}"
        )


def version_for(session: Session, program: str, number: int | None) -> ProgramVersion:
    """The version a send, drip-feed or put of ``program`` means: ``number``, or without it
    the released one (none released: refused with 409), for the API and the pages alike."""
    return jobs.version_to_send(session, program, number)
