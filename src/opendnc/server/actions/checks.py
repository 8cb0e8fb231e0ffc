"""Program checks: the dry run of a library version, alone or against a configured machine.

A version is checked when it is saved (an upload, an edit), and when it is released or sent
(a stored check is read again, never run twice); a page or the API asking for a check that
was never run (a version from the folder watcher, the inbox) runs it then. Every run happens
outside a write transaction (a check may take seconds; the database's write lock must not
wait for it) and in the caller's thread (the routes run in the thread pool).
"""

from __future__ import annotations

from dataclasses import dataclass

from sqlalchemy.orm import Session

from opendnc.nccheck import MachineLimits, limits_for
from opendnc.server.actions.base import Caller, Services, require
from opendnc.server.actions.models import CheckOut, LiveCheckOut, ProblemOut
from opendnc.server.library import checks as program_checks
from opendnc.server.library import versions as library
from opendnc.server.library.checks import Checked
from opendnc.server.store.models import ProgramVersion, Role

__all__ = [
    "Target",
    "check_out",
    "ensure",
    "limits_of",
    "live_check",
    "machine_checks",
    "version_check",
]


@dataclass(frozen=True)
class Target:
    """The version a check is of (read in one transaction, used in another)."""

    version_id: int
    program: str
    number: int
    sha256: str

    @classmethod
    def of(cls, version: ProgramVersion) -> Target:
        """From the row (its program loaded with it)."""
        return cls(version.id, version.program.name, version.number, version.sha256)


def limits_of(svc: Services, machine: str) -> MachineLimits:
    """What the check of a program for ``machine`` knows of it: family, envelope, protected
    program numbers (:func:`opendnc.nccheck.limits_for`)."""
    return limits_for(svc.machine(machine).config)


def _library(svc: Services) -> program_checks.Library:
    return program_checks.library_lookup(svc.reads)


def ensure(svc: Services, target: Target, limits: MachineLimits | None) -> Checked:
    """The check of ``target`` against ``limits`` (None: the text alone): the stored one, or
    a new dry run, stored. Runs no write transaction while the dry run goes."""
    key = program_checks.limits_key(limits)
    found = svc.read(lambda s: program_checks.load(s, target.version_id, key))
    if found is not None:
        return found
    data = svc.read(lambda s: library.content(s, _version_row(s, target)))
    result = program_checks.run(target.program, data, limits, _library(svc))
    return svc.write(lambda s: program_checks.store(s, target.version_id, key, result))


def _version_row(session: Session, target: Target) -> ProgramVersion:
    return library.get_version(session, target.program, target.number)


def in_transaction(
    svc: Services, session: Session, version: ProgramVersion, limits: MachineLimits | None
) -> Checked:
    """The stored check of ``version`` within a write transaction (the callers run
    :func:`ensure` before it, so this is a read; a version changed meanwhile is checked
    here)."""
    key = program_checks.limits_key(limits)
    found = program_checks.load(session, version.id, key)
    if found is not None:
        return found
    data = library.content(session, version)
    result = program_checks.run(version.program.name, data, limits, _library(svc))
    return program_checks.store(session, version.id, key, result)


def check_out(target: Target, check: Checked, machine: str | None) -> CheckOut:
    """The API's view of a stored check."""
    return CheckOut(
        program=target.program,
        version=target.number,
        sha256=target.sha256,
        machine=machine,
        control=check.control,
        ok=check.ok,
        errors=check.errors,
        warnings=check.warnings,
        summary=check.summary,
        problems=[ProblemOut(**p) for p in check.problems],
        facts=check.facts,
        checked=check.checked,
    )


def _target(svc: Services, name: str, number: int | None) -> Target:
    library.check_program_name(name)
    return svc.read(lambda s: Target.of(library.get_version(s, name, number)))


def version_check(
    svc: Services, who: Caller, name: str, number: int | None, machine: str | None = None
) -> CheckOut:
    """The program check of version ``number`` of ``name`` (the newest without it), of the
    text alone or, with ``machine``, as that machine would take it (its family, travel and
    protected program numbers: ``opendnc check --machine``)."""
    require(who, Role.VIEWER)
    limits = limits_of(svc, machine) if machine else None
    target = _target(svc, name, number)
    return check_out(target, ensure(svc, target, limits), machine)


def machine_checks(
    svc: Services, who: Caller, name: str, number: int | None, machines: list[str]
) -> list[CheckOut]:
    """The checks of one version for each of ``machines`` (machines alike share one run)."""
    require(who, Role.VIEWER)
    target = _target(svc, name, number)
    return [check_out(target, ensure(svc, target, limits_of(svc, m)), m) for m in machines]


def live_check(svc: Services, who: Caller, name: str, data: bytes) -> LiveCheckOut:
    """The check of ``data``, the text of ``name`` as it is being edited (programmers: the
    editor's marks). Nothing is stored; the run is bounded like every check (at most
    :data:`~opendnc.server.library.checks.PARALLEL` at once, the checker's budget), so call it
    from a worker thread."""
    require(who, Role.PROGRAMMER)
    library.check_program_name(name)
    result = program_checks.run(name, data, None, _library(svc))
    return LiveCheckOut(
        ok=not result.errors,
        errors=len(result.errors),
        warnings=len(result.warnings),
        summary=program_checks.summary_of(result),
        problems=[ProblemOut(**p) for p in program_checks.problems_of(result)],
    )
