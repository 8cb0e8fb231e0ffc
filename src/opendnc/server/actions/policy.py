"""The rules every request to the queue passes: which role each kind of job needs, what a
machine takes (``released_only``, the drip-feed opt-in, the file browser), what a version
means when none is named, and what a program check's errors block (a release, a send, a
drip-feed) and who may override them. Nothing else in the server decides these: a job queued
from the API or a page, a retry and a control's remote request
(:mod:`opendnc.server.remote_request`) all ask :func:`may_put_on`."""

from __future__ import annotations

import hashlib
from collections.abc import Callable

from sqlalchemy import select
from sqlalchemy.orm import Session, contains_eager, joinedload

from opendnc.errors import InputError
from opendnc.nccheck import limits_for
from opendnc.server import jobs
from opendnc.server.actions import checks
from opendnc.server.actions.base import Caller, Services, require
from opendnc.server.capabilities import capabilities_of
from opendnc.server.config import MachineConfig
from opendnc.server.errors import Conflict
from opendnc.server.kinds.base import SharedMachine
from opendnc.server.program_checks import Checked
from opendnc.server.store.models import JobKind, Program, ProgramState, ProgramVersion, Role

__all__ = [
    "CHECKED_JOBS",
    "JOB_ROLES",
    "OVERRIDE_ROLE",
    "TAKE_BACK_ROLE",
    "CheckFailed",
    "check_machine",
    "check_passes",
    "may_put_on",
    "may_queue",
    "may_take_back",
    "override_reason",
    "share_gate",
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
            f"{machine.name} does not allow drip-feed (dripfeed = true in its configuration "
            "enables it on a serial Haas or a serial tape control)"
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


# Jobs that put a library version on a machine to run: its program check must pass there.
# (A put_file is the file browser's: any file, a tool table too; it needs a programmer, who
# may override anyway.)
CHECKED_JOBS = frozenset({JobKind.SEND, JobKind.DRIPFEED})
# Who may release or send a version although its program check found errors (with a reason).
OVERRIDE_ROLE = Role.PROGRAMMER


def override_reason(who: Caller, override: str | None) -> str | None:
    """The reason of an override of a program check's errors, or None when none is given.

    An override needs the programmer role (403) and a reason that is not blank (400), whether
    or not the check finds errors: the request is refused the same way every time."""
    if override is None:
        return None
    require(who, OVERRIDE_ROLE)
    reason = " ".join(override.split())
    if not reason:
        raise InputError("an override of the program check needs a reason")
    return reason


class CheckFailed(Conflict):
    """A release or a send refused because the version's program check found errors and
    nobody overrode them (HTTP 409, like any conflict); ``check`` is that check, for a
    caller that tells someone in its own words (a control's request report)."""

    def __init__(self, message: str, check: Checked) -> None:
        super().__init__(message)
        self.check = check


def check_passes(check: Checked, reason: str | None, what: str, *, blocks: bool = True) -> bool:
    """Refuse (409) ``what`` (``"P.H v3 to tnc1"``) when ``check`` found errors and there is
    no override ``reason``; True when the override lets it through (the caller audits it).
    ``blocks`` is the shop's ``[library] check`` (False for ``"warn"``: errors are shown
    only, nothing is refused or overridden)."""
    if check.ok or not blocks:
        return False
    if reason is not None:
        return True
    first = check.first_error() or {}
    count = f"{check.errors} error{'s' * (check.errors != 1)}"
    where = "on" if check.errors == 1 else "the first on"
    raise CheckFailed(
        f"{what}: the program check found {count}, {where} line {first.get('line', '?')}: "
        f"{first.get('message', '')}; a programmer may override it with a reason",
        check,
    )


def may_put_on(
    svc: Services,
    session: Session,
    machine: MachineConfig,
    kind: JobKind,
    version: ProgramVersion | None,
    reason: str | None,
) -> Checked | None:
    """Whether a ``kind`` job of ``version`` may go to ``machine``, within the write
    transaction that queues it: refused (409) where the machine does not take it
    (:func:`check_machine`), or, for a send or a drip-feed, where the version's program
    check for that machine (its family, travel, protected numbers) finds errors and there
    is no override ``reason`` (:class:`CheckFailed`). Returns the check when an override
    lets it through (the caller audits it), else None.

    The check is read from ``version_checks``: the caller runs :func:`checks.ensure` for
    the machine before the transaction, so no dry run holds the write lock."""
    check_machine(machine, kind, version)
    if kind not in CHECKED_JOBS or version is None:
        return None
    check = checks.in_transaction(svc, session, version, limits_for(machine))
    what = f"{version.program.name} v{version.number} to {machine.name}"
    blocks = svc.runner.config.library.check_blocks
    return check if check_passes(check, reason, what, blocks=blocks) else None


def share_gate(svc: Services) -> Callable[[SharedMachine, str, bytes], str | None]:
    """The net share's gate (:class:`opendnc.server.netshare.NetShare`): whether a NAS file
    may be copied into a machine's share, by the same rule as a send (:func:`may_put_on`),
    for the library version it is (by name and content; the released one where several
    match). None: it may; else why not. A file the library never saw, or an edit of a
    program the library does not hold, is no version: a ``released_only`` machine refuses
    it; another takes it (the NAS folder is the shop's drop folder), unchecked. A check's
    errors block: nobody stands at the NAS to override them with a reason."""

    def gate(seat: SharedMachine, name: str, data: bytes) -> str | None:
        machine = seat.config
        digest = hashlib.sha256(data).hexdigest()

        def find(session: Session) -> checks.Target | None:
            version = session.scalar(
                select(ProgramVersion)
                .join(Program, ProgramVersion.program_id == Program.id)
                .where(Program.name == name, ProgramVersion.sha256 == digest)
                .options(contains_eager(ProgramVersion.program))
                .order_by(
                    (ProgramVersion.state == ProgramState.RELEASED).desc(),
                    ProgramVersion.number.desc(),
                )
                .limit(1)
            )
            return checks.Target.of(version) if version is not None else None

        target = svc.read(find)
        if target is None:
            if machine.released_only:
                return (
                    f"{machine.name} accepts released programs only; the library has no "
                    f"version of {name} with this content"
                )
            return None
        checks.ensure(svc, target, limits_for(machine))  # the dry run outside the write

        def decide(session: Session) -> str | None:
            version = session.get(
                ProgramVersion, target.version_id, options=[joinedload(ProgramVersion.program)]
            )
            if version is None:
                return f"{name}: its library version is gone"
            try:
                may_put_on(svc, session, machine, JobKind.SEND, version, None)
            except Conflict as exc:
                return str(exc)
            return None

        return svc.write(decide)

    return gate
