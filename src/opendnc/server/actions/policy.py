"""The rules every program that goes to a machine passes, decided in one place.

Which role each kind of job needs, what a machine takes (``released_only``, the drip-feed
opt-in, the file browser), which version a request means (:func:`resolve`, the one version
rule), and what a program check's errors block (a release, a send, a drip-feed) and who may
override them. Queue, retry, a control's remote request, the file browser's put, a release
and the net share all ask :func:`authorize`, which returns a :class:`Decision`:

1. **prepared** outside any write transaction: the role, the override's reason, the version
   the request means, each machine's rule, and the program check for each machine (a dry
   run may take seconds, and must not hold the write lock);
2. **confirmed** inside the caller's write transaction (:meth:`Decision.confirm`): the
   version is resolved again (a release meanwhile makes a stale decision, refused) and its
   approval state, each machine's policy and the stored check are read again, so what is
   committed is what was decided at the commit, not a moment before.

Nothing else in the server decides these."""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from enum import StrEnum

from sqlalchemy import select
from sqlalchemy.orm import Session, contains_eager

from opendnc.errors import DncError, InputError, UsageError
from opendnc.nccheck import MachineLimits, limits_for
from opendnc.server.actions import checks
from opendnc.server.actions.base import Caller, Services, require
from opendnc.server.config.shop import MachineConfig
from opendnc.server.core.errors import Conflict
from opendnc.server.jobs import queue as jobs
from opendnc.server.kinds.base import SharedMachine
from opendnc.server.kinds.capabilities import capabilities_of
from opendnc.server.library import versions as library
from opendnc.server.library.checks import Checked
from opendnc.server.store import audit
from opendnc.server.store.models import JobKind, Program, ProgramState, ProgramVersion, Role

__all__ = [
    "CHECKED_JOBS",
    "JOB_ROLES",
    "OVERRIDE_ROLE",
    "TAKE_BACK_ROLE",
    "Action",
    "CheckFailed",
    "Decision",
    "Override",
    "Refusal",
    "Stale",
    "Verdict",
    "Via",
    "Wanted",
    "authorize",
    "check_passes",
    "may_queue",
    "may_take_back",
    "override_reason",
    "record_override",
    "resolve",
    "share_gate",
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


class Via(StrEnum):
    """The six ways a program reaches a machine (or the shop's machines, for a release)."""

    QUEUE = "queue"  # a job from the API, a page or an action of its own (a take-back)
    RETRY = "retry"  # a finished, unsuccessful job queued again
    REQUEST = "request"  # a control's remote request (nobody there can override a check)
    PUT_FILE = "put_file"  # the file browser's upload: a draft stored, then put on the control
    RELEASE = "release"  # a version released for every machine (its text checked alone)
    SHARE = "share"  # the net share's copy of a NAS file (nobody at the NAS overrides)


@dataclass(frozen=True)
class Action:
    """What is asked: ``via`` which path, and the ``kind`` of job it puts on the machines
    (None for a release, which puts nothing anywhere)."""

    via: Via
    kind: JobKind | None

    @classmethod
    def queue(cls, kind: JobKind) -> Action:
        """A new ``kind`` job."""
        return cls(Via.QUEUE, kind)

    @classmethod
    def retry(cls, kind: JobKind) -> Action:
        """A ``kind`` job queued again."""
        return cls(Via.RETRY, kind)

    @classmethod
    def request(cls) -> Action:
        """A send a control asked for."""
        return cls(Via.REQUEST, JobKind.SEND)

    @classmethod
    def put_file(cls) -> Action:
        """A file from a person's computer put on the control."""
        return cls(Via.PUT_FILE, JobKind.PUT_FILE)

    @classmethod
    def release(cls) -> Action:
        """A version released."""
        return cls(Via.RELEASE, None)

    @classmethod
    def share(cls) -> Action:
        """A NAS file copied into a machine's share: a send by other means."""
        return cls(Via.SHARE, JobKind.SEND)


@dataclass(frozen=True)
class Wanted:
    """The version a request means, before :func:`resolve` reads it: ``number`` of
    ``program`` (without it, the released one), or, with ``sha256``, the version holding
    that content (the net share's file; the released one where several do)."""

    program: str
    number: int | None = None
    sha256: str | None = None


def resolve(session: Session, wanted: Wanted) -> ProgramVersion | None:
    """The one version rule: the version ``wanted`` means (its program loaded with it).

    By number or by "the released one", :func:`opendnc.server.jobs.queue.version_to_send`: an
    unknown program or number is :class:`~opendnc.server.core.errors.NotFound` (404), no released
    version :class:`~opendnc.server.jobs.queue.NotReleased` (409). By content: None where the
    library holds no such version (a file it never saw, an edit not stored)."""
    if wanted.sha256 is None:
        return jobs.version_to_send(session, wanted.program, wanted.number)
    return session.scalar(
        select(ProgramVersion)
        .join(Program, ProgramVersion.program_id == Program.id)
        .where(Program.name == wanted.program, ProgramVersion.sha256 == wanted.sha256)
        .options(contains_eager(ProgramVersion.program))
        .order_by(
            (ProgramVersion.state == ProgramState.RELEASED).desc(),
            ProgramVersion.number.desc(),
        )
        .limit(1)
    )


class Refusal(StrEnum):
    """Why a machine (or, for a release, the library) refuses what was asked."""

    NO_DRIPFEED = "no_dripfeed"  # the machine's drip-feed opt-in is off (or its kind has none)
    NO_FILE_BROWSER = "no_file_browser"
    RELEASED_ONLY = "released_only"  # the version is not released
    NOT_IN_LIBRARY = "not_in_library"  # the net share's file is no version; released only
    CHECK_FAILED = "check_failed"  # the program check's errors, and no override


@dataclass(frozen=True)
class Override:
    """An override of a program check's errors: ``who`` gave it and ``why``."""

    who: str
    why: str


@dataclass(frozen=True)
class Verdict:
    """One machine's answer (``machine`` None: a release's check of the text alone).

    ``check`` is the program check read for it (None where none applies or the machine's
    own rule refused first); ``overridden`` is True where the check found errors and the
    override lets them through (the caller audits it: :func:`record_override`)."""

    machine: str | None
    refusal: Refusal | None = None
    reason: str = ""  # the refusal in the policy's words
    check: Checked | None = None
    overridden: bool = False

    @property
    def allowed(self) -> bool:
        """True where the request may go."""
        return self.refusal is None

    def error(self) -> Conflict:
        """The refusal as the error a caller raises (409; :class:`CheckFailed` for a check)."""
        if self.refusal is Refusal.CHECK_FAILED and self.check is not None:
            return CheckFailed(self.reason, self.check)
        return Conflict(self.reason)


class Stale(Conflict):
    """A decision whose version changed between its preparation and its confirmation (a
    release meanwhile changes what "the released one" is): refused, 409; asked again, it is
    decided afresh."""


Actor = Caller | str
"""Who asks: a person (a :data:`Caller`, whose role is checked) or the server itself on
behalf of a control or the NAS (a name, for the audit trail: ``request@mill-1``)."""


@dataclass(frozen=True)
class Decision:
    """What :func:`authorize` decided: the ``version`` it means (None: a job of no library
    version, or a NAS file the library never saw), each machine's :class:`Verdict` (one per
    machine, in the order asked; a release has one, of the text), and the ``override``
    that applies. Prepared outside the write transaction, it must be confirmed inside it
    (:meth:`confirm`) before anything is committed on its word; ``row`` is the version's
    row in the confirming session."""

    services: Services = field(repr=False, compare=False)
    action: Action
    actor: str
    wanted: Wanted | None
    machines: tuple[str, ...]
    version: checks.Target | None
    state: ProgramState | None
    verdicts: tuple[Verdict, ...]
    override: Override | None
    confirmed: bool = False
    row: ProgramVersion | None = field(default=None, repr=False, compare=False)

    @property
    def allowed(self) -> tuple[Verdict, ...]:
        """The verdicts that let the request go."""
        return tuple(v for v in self.verdicts if v.allowed)

    @property
    def refused(self) -> tuple[Verdict, ...]:
        """The verdicts that refuse it: the machines' own rules (which no override lifts)
        first, then the program checks' errors, each in the order asked."""
        refused = [v for v in self.verdicts if not v.allowed]
        rules = [v for v in refused if v.refusal is not Refusal.CHECK_FAILED]
        return tuple(rules + [v for v in refused if v.refusal is Refusal.CHECK_FAILED])

    def verdict(self, machine: str | None) -> Verdict:
        """The verdict of ``machine``."""
        return next(v for v in self.verdicts if v.machine == machine)

    def first_refusal(self) -> Verdict | None:
        """The refusal to say when the request goes everywhere or nowhere: a machine's own
        rule before a program check's errors."""
        refused = self.refused
        return refused[0] if refused else None

    def require_all(self) -> None:
        """Raise the first refusal (:meth:`first_refusal`), if any machine refuses."""
        first = self.first_refusal()
        if first is not None:
            raise first.error()

    def confirm(self, session: Session, created: ProgramVersion | None = None) -> Decision:
        """This decision again, within the write transaction ``session`` that acts on it:
        the version resolved again (another one now: :class:`Stale`), its state, each
        machine's policy and the stored checks read again. ``created`` is the version the
        transaction itself stored (the file browser's put), decided here for the first
        time."""
        if self.confirmed:
            raise UsageError("a decision is confirmed once, in the transaction it commits")
        row: ProgramVersion | None = None
        if created is not None:
            if self.action.via is not Via.PUT_FILE:
                raise UsageError("only a put decides on a version its transaction stored")
            row = created
        elif self.wanted is not None:
            row = resolve(session, self.wanted)
            before = self.version.version_id if self.version is not None else None
            if (row.id if row is not None else None) != before:
                raise Stale(
                    f"{self.wanted.program}: {_named(self.version)} was decided on, the "
                    f"library now holds {_named(row)}; ask again"
                )
        svc = self.services

        def check(limits: MachineLimits | None) -> Checked:
            assert row is not None  # a check is read only for a version
            return checks.in_transaction(svc, session, row, limits)

        configs = [svc.machine(name).config for name in self.machines]
        target = checks.Target.of(row) if row is not None else None
        state = row.state if row is not None else None
        verdicts = _judge(svc, self.action, configs, target, state, self.override, check)
        return replace(
            self,
            version=target,
            state=state,
            verdicts=verdicts,
            confirmed=True,
            row=row,
        )


def _named(version: checks.Target | ProgramVersion | None) -> str:
    if version is None:
        return "no version"
    number = version.number
    return f"version {number}"


def authorize(
    svc: Services,
    actor: Actor,
    version: Wanted | None,
    machines: Sequence[str],
    action: Action,
    *,
    override: str | Override | None = None,
) -> Decision:
    """Decide whether ``actor`` may put ``version`` on each of ``machines`` by ``action``;
    the decision is prepared here, outside any write transaction, and confirmed by the
    caller inside its own (:meth:`Decision.confirm`).

    Refused whole (raised): the role (403), an override's missing reason (400), an unknown
    machine, program or version (404), no released version where none is named (409), a
    program job without a program (400). Refused per machine (a :class:`Verdict`): the
    machine's rule, then the program check for that machine, which a send, a drip-feed and
    a release must pass unless ``override`` gives a reason (a string: the caller's own,
    programmers only; an :class:`Override`: one given before, a retry's)."""
    name = _may(actor, action)
    given = _override(actor, action, override)
    if version is None and action.kind in jobs.PROGRAM_JOBS and action.via is not Via.PUT_FILE:
        raise InputError(f"a {action.kind.value} job names a program")
    if action.via is Via.PUT_FILE and version is not None:
        raise UsageError("a put decides on the version its transaction stores (confirm)")
    configs = [svc.machine(m).config for m in machines]
    if version is not None and action.via is not Via.SHARE:  # a NAS file may be named anyhow
        library.check_program_name(version.program)
    row = svc.read(lambda s: _snapshot(s, version))
    target, state = row if row is not None else (None, None)

    def check(limits: MachineLimits | None) -> Checked:
        assert target is not None  # a check is run only for a version
        return checks.ensure(svc, target, limits)  # the dry run, before the transaction

    verdicts = _judge(svc, action, configs, target, state, given, check)
    return Decision(
        services=svc,
        action=action,
        actor=name,
        wanted=version,
        machines=tuple(c.name for c in configs),
        version=target,
        state=state,
        verdicts=verdicts,
        override=given,
    )


def _snapshot(session: Session, wanted: Wanted | None) -> tuple[checks.Target, ProgramState] | None:
    row = resolve(session, wanted) if wanted is not None else None
    return (checks.Target.of(row), row.state) if row is not None else None


def _may(actor: Actor, action: Action) -> str:
    """The actor's name, once its role allows ``action`` (403 otherwise)."""
    if isinstance(actor, str):
        if action.via not in (Via.REQUEST, Via.SHARE):
            raise UsageError(f"a {action.via.value} is asked by a person, not by the server")
        return actor
    if action.via is Via.RELEASE:
        require(actor, Role.APPROVER)
    elif action.kind is not None and (action.via is not Via.RETRY or action.kind in JOB_ROLES):
        may_queue(actor, action.kind)  # a report is the server's own, retried like any job
    return actor.name


def _override(actor: Actor, action: Action, override: str | Override | None) -> Override | None:
    if override is None:
        return None
    if action.via in (Via.REQUEST, Via.SHARE):
        raise UsageError(f"nobody can give a reason at a {action.via.value}: no override")
    if isinstance(override, Override):
        return override
    assert not isinstance(actor, str)  # _may let only a person through
    reason = override_reason(actor, override)
    return Override(actor.name, reason) if reason is not None else None


def _judge(
    svc: Services,
    action: Action,
    configs: Sequence[MachineConfig],
    version: checks.Target | None,
    state: ProgramState | None,
    override: Override | None,
    check: Callable[[MachineLimits | None], Checked],
) -> tuple[Verdict, ...]:
    """Each machine's verdict: its own rule first, then the program check for it."""
    blocks = svc.runner.config.library.check_blocks
    reason = override.why if override is not None else None
    if action.via is Via.RELEASE:
        assert version is not None  # a release names its version
        what = f"{version.program} v{version.number}"
        return (_checked(None, check(None), reason, what, blocks),)
    verdicts = []
    for config in configs:
        refused = _machine_rule(config, action, version, state)
        if refused is not None:
            verdicts.append(refused)
        elif action.kind in CHECKED_JOBS and version is not None:
            what = f"{version.program} v{version.number} to {config.name}"
            verdicts.append(_checked(config.name, check(limits_for(config)), reason, what, blocks))
        else:
            verdicts.append(Verdict(config.name))
    return tuple(verdicts)


def _machine_rule(
    machine: MachineConfig,
    action: Action,
    version: checks.Target | None,
    state: ProgramState | None,
) -> Verdict | None:
    """``machine``'s refusal of ``action`` with ``version``, or None where it takes it."""
    caps = capabilities_of(machine)
    name = machine.name
    if action.kind is JobKind.DRIPFEED and not caps.dripfeed:
        return Verdict(
            name,
            Refusal.NO_DRIPFEED,
            f"{name} does not allow drip-feed (dripfeed = true in its configuration "
            "enables it on a serial Haas or a serial tape control)",
        )
    if action.kind is JobKind.PUT_FILE and not caps.file_browser:
        return Verdict(name, Refusal.NO_FILE_BROWSER, f"{name} has no file browser")
    if not machine.released_only:
        return None
    if version is not None and state is not ProgramState.RELEASED:
        assert state is not None
        return Verdict(
            name,
            Refusal.RELEASED_ONLY,
            f"{name} accepts released programs only; {version.program} "
            f"version {version.number} is {state.value}",
        )
    if version is None and action.via is Via.SHARE:
        return Verdict(name, Refusal.NOT_IN_LIBRARY, f"{name} accepts released programs only")
    return None


def _checked(
    machine: str | None, check: Checked, reason: str | None, what: str, blocks: bool
) -> Verdict:
    try:
        overridden = check_passes(check, reason, what, blocks=blocks)
    except CheckFailed as failed:
        return Verdict(machine, Refusal.CHECK_FAILED, str(failed), check)
    return Verdict(machine, None, "", check, overridden)


def record_override(
    session: Session, decision: Decision, verdict: Verdict, *, job_id: int | None = None
) -> None:
    """The ``program.check_override`` audit row of ``verdict``'s override: who gave the
    reason and which, the check's errors and its first, for the job ``job_id`` (None for
    a release)."""
    override, version = decision.override, decision.version
    if not verdict.overridden or override is None or version is None or verdict.check is None:
        return
    kind = decision.action.kind
    audit.record(
        session,
        decision.actor,
        "program.check_override",
        machine=verdict.machine,
        program=version.program,
        sha256=version.sha256,
        job_id=job_id,
        version=version.number,
        to=kind.value if kind is not None else "release",
        reason=override.why,
        by=override.who,
        errors=verdict.check.errors,
        first=verdict.check.first_error(),
    )


SHARE_ACTOR = "netshare"  # the audit's name of the net share (opendnc.server.netshare.share.ACTOR)


def share_gate(svc: Services) -> Callable[[SharedMachine, str, bytes], str | None]:
    """The net share's gate (:class:`opendnc.server.netshare.share.NetShare`): whether a NAS file
    may be copied into a machine's share, decided by :func:`authorize` like a send, for the
    library version the file is (same name and content; the released one where several
    are). None: it may; else why not. A file the library never saw, or an edit not stored
    as a version, is no version: a ``released_only`` machine refuses it; another takes it
    (the NAS folder is the shop's drop folder), unchecked. A check's errors block: nobody
    stands at the NAS to override them with a reason."""

    def gate(seat: SharedMachine, name: str, data: bytes) -> str | None:
        machine = seat.config
        wanted = Wanted(name, sha256=hashlib.sha256(data).hexdigest())
        try:
            prepared = authorize(svc, SHARE_ACTOR, wanted, [machine.name], Action.share())
            decision = svc.write(prepared.confirm)
        except DncError as exc:  # the version changed meanwhile: asked again next scan
            return str(exc)
        verdict = decision.verdict(machine.name)
        if verdict.refusal is Refusal.NOT_IN_LIBRARY:
            return f"{verdict.reason}; the library has no version of {name} with this content"
        return None if verdict.allowed else verdict.reason

    return gate
