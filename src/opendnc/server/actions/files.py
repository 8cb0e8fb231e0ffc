"""Files on a control, from the dashboard's file browser (or the API).

Reading (a listing, a download) is an errand on the machine's own connector, run by its
task between jobs (:class:`opendnc.server.kinds.files.Errands`): no second link to the
control. Changing a file is a job like every other, under the same rules: a file from a
person's computer enters the library as a draft first and is then put on the control by a
``put_file`` job, which the machine's policy may refuse (``released_only`` takes no draft);
a delete is a ``delete`` job and needs the programmer role; a receive job brings a file to
the inbox under its own name.
"""

from __future__ import annotations

import hashlib

from sqlalchemy import select
from sqlalchemy.orm import Session

from opendnc.server.actions import policy, queue
from opendnc.server.actions.base import Caller, Services, require
from opendnc.server.actions.models import Content, FolderOut, JobOut, JobRequest, RemoteFileOut
from opendnc.server.actions.policy import may_queue, may_take_back
from opendnc.server.config.shop import MachineConfig
from opendnc.server.core.errors import Conflict, Unavailable
from opendnc.server.core.events import ProgramChanged
from opendnc.server.jobs import queue as jobs
from opendnc.server.kinds.capabilities import capabilities_of
from opendnc.server.kinds.connector import Connector
from opendnc.server.kinds.files import browser_of, check_path, file_name
from opendnc.server.kinds.registry import program_folder_of
from opendnc.server.library import versions as library
from opendnc.server.store.models import JobKind, Program, Role

__all__ = ["delete_file", "list_folder", "put_file", "read_file", "receive_file", "take_back"]

ERRAND_TIMEOUT = 15.0  # a listing waits this long for the machine's task (a job may run)


def _browsable(svc: Services, name: str) -> MachineConfig:
    state = svc.machine(name)
    if not capabilities_of(state.config).file_browser:
        raise Conflict(f"{name} has no file browser")
    if not state.online:
        reason = f": {state.last_error}" if state.last_error else ""
        raise Unavailable(f"{name} is offline{reason}")
    return state.config


async def list_folder(svc: Services, who: Caller, machine: str, folder: str | None) -> FolderOut:
    """The entries of ``folder`` on the control (the machine's program folder without it),
    folders first, then by name."""
    require(who, Role.VIEWER)
    config = _browsable(svc, machine)
    where = check_path(folder) if folder else program_folder_of(config)

    async def listing(connector: Connector) -> list[RemoteFileOut]:
        found = await browser_of(connector).list_files(where)
        return [RemoteFileOut.of(f) for f in found if f.name not in {".", ".."}]

    entries = await svc.machine(machine).errands.call(
        listing, lambda: svc.runner.wake(machine), ERRAND_TIMEOUT
    )
    entries.sort(key=lambda f: (not f.is_dir, f.name.lower()))
    parent = where.rsplit("/", 1)[0] if where.count("/") > 1 else "TNC:/"
    return FolderOut(
        machine=machine,
        folder=where,
        parent=parent if where != "TNC:/" else None,
        entries=entries,
    )


async def read_file(svc: Services, who: Caller, machine: str, path: str) -> Content:
    """The bytes of a file on the control, read on the machine's own link."""
    require(who, Role.VIEWER)
    config = _browsable(svc, machine)
    target = check_path(path)

    async def fetch(connector: Connector) -> bytes:
        return await browser_of(connector).fetch(target)

    data = await svc.machine(config.name).errands.call(
        fetch, lambda: svc.runner.wake(machine), ERRAND_TIMEOUT
    )
    return Content(file_name(target), hashlib.sha256(data).hexdigest(), data)


def put_file(
    svc: Services, who: Caller, machine: str, folder: str, filename: str, data: bytes
) -> JobOut:
    """Store ``data`` in the library as a draft of ``filename`` (programmers), then queue
    a ``put_file`` job of that version to ``folder/filename`` on the control, under the
    machine's policy. A refusal stores nothing."""
    # the role and the machine's file browser now; the version is the draft stored below
    prepared = policy.authorize(svc, who, None, [machine], policy.Action.put_file())
    name = library.check_program_name(filename)
    target = check_path(f"{check_path(folder)}/{name}")
    prepared.require_all()

    def store(session: Session) -> JobOut:
        version, _ = library.add_version(
            session, name, data, author=who.name, comment=f"put on {machine} as {target}"
        )
        # a refusal (released_only takes no draft) rolls the draft back too
        prepared.confirm(session, created=version).require_all()
        job = jobs.enqueue(
            session,
            JobKind.PUT_FILE,
            machine,
            actor=who.name,
            version=version,
            params={"path": target},
        )
        return JobOut.of(job)

    out = svc.write(store)
    svc.changed(ProgramChanged(name))
    svc.queued([out])
    return out


def delete_file(svc: Services, who: Caller, machine: str, path: str) -> JobOut:
    """Queue a ``delete`` job of the file ``path`` on the control (programmers)."""
    may_queue(who, JobKind.DELETE)
    order = JobRequest(kind=JobKind.DELETE, path=check_path(path), machines=[machine])
    return queue.create_jobs(svc, who, order)[0]


def receive_file(svc: Services, who: Caller, machine: str, path: str) -> JobOut:
    """Queue a ``receive`` job: the file comes to the inbox under its own name."""
    may_queue(who, JobKind.RECEIVE)
    order = JobRequest(kind=JobKind.RECEIVE, path=check_path(path), machines=[machine])
    return queue.create_jobs(svc, who, order)[0]


def take_back(svc: Services, who: Caller, machine: str, path: str) -> JobOut:
    """Queue a ``receive`` job that stores the control's file as a new draft version of the
    library program of the file's name (programmers): what the operator changed at the
    control comes back into the library, beside the versions it came from. A program that
    is locked is refused now (409); one locked before the job runs keeps the file in the
    inbox (the job says so)."""
    may_take_back(who)
    target = check_path(path)
    name = library.check_program_name(file_name(target))
    if not capabilities_of(svc.machine(machine).config).file_browser:
        raise Conflict(f"{machine} has no file browser")

    def check(session: Session) -> None:
        program = session.scalar(select(Program).where(Program.name == name))
        if program is not None and program.locked:
            raise Conflict(f"program {name!r} is locked: unlock it to take {target} back")

    svc.read(check)
    order = JobRequest(kind=JobKind.RECEIVE, path=target, machines=[machine])
    return queue.create_jobs(svc, who, order, extra={"into_library": True, "by": who.name})[0]
