"""Programs a control sends by itself (a punch): into the inbox, or answered as a remote
request (docs/server.md#receiving-and-remote-request).

The rules that tell a request from a program are :mod:`opendnc.server.requests`; this component
applies them to each reception a machine's task hands it, queues the requested programs after
the request delay (the released version; the newest where the machine takes drafts) and the
report programs the settings ask for, and wakes the machine when the answer falls due.

A requested program goes out under the rules a send from the API meets
(:func:`opendnc.server.actions.policy.may_put_on`): a version whose program check for this
machine finds errors is not sent (nobody at the control can override it) and the report says
so, with the first error's line.
"""

from __future__ import annotations

import asyncio
import logging
import textwrap
from datetime import datetime, timedelta
from pathlib import Path
from typing import Any

from sqlalchemy.orm import Session, sessionmaker

from opendnc.errors import InputError
from opendnc.server import audit, inbox, jobs, library, requests
from opendnc.server.actions import checks, policy
from opendnc.server.actions.base import Services
from opendnc.server.config import MachineConfig
from opendnc.server.errors import Conflict, NotFound
from opendnc.server.events import ProgramReceived, publish_job_queued
from opendnc.server.kinds.registry import capabilities_of
from opendnc.server.machine_state import Machines, MachineState
from opendnc.server.machines.base import Reception
from opendnc.server.requests import RequestSettings
from opendnc.server.store.models import JobKind, ProgramVersion, utcnow

__all__ = ["RemoteRequests"]

log = logging.getLogger(__name__)


class RemoteRequests:
    """Files receptions and answers requests; a component with nothing to start."""

    name = "remote-requests"
    needs = ("machines", "actions")

    def __init__(
        self,
        machines: Machines,
        services: Services,
        settings: RequestSettings,
        inbox_folder: Path,
    ) -> None:
        self.machines = machines
        self.services = services  # a send's rules: the actions layer's (policy.may_put_on)
        self.sessions: sessionmaker[Session] = services.sessions
        self.settings = settings
        self.inbox_folder = inbox_folder

    async def start(self) -> None:
        """Nothing to start."""

    async def stop(self) -> None:
        """Nothing to stop."""

    async def received(self, state: MachineState, reception: Reception) -> None:
        """File a program the control sent: into the inbox, or answer it as a request."""
        settings = self.settings
        machine = state.config
        if reception.failed and not reception.data:
            # Broke off before a single byte of a program: nothing was received (what a
            # control sends as a stopped drip-feed leaves its DNC mode looks like a start).
            # Not an inbox item, nor the machine's last error.
            log.info("%s: a reception that brought nothing: %s", machine.name, reception.failed)
            return
        folder = self.inbox_folder
        zone = self.machines.config.calendar.zone
        queued: list[dict[str, Any]] = []  # the requested programs' jobs, announced once committed

        def handle() -> tuple[str, float | None]:
            names = None if reception.failed else requests.find_request(reception.data, settings)
            if names is not None:
                self._check(machine, names)  # the dry runs before the write transaction
            with self.sessions.begin() as session:
                if reception.failed:
                    row = inbox.store(
                        session,
                        machine.name,
                        reception.data,
                        folder=folder,
                        failed=reception.failed,
                        zone=zone,
                    )
                    return f"reception failed: {row.reason}", None
                if names is None:
                    row = inbox.store(
                        session,
                        machine.name,
                        reception.data,
                        folder=folder,
                        zone=zone,
                        name=reception.name,
                    )
                    if settings.reports == "all":
                        self._report(session, machine, "RECEIVED", [f"{row.name} IN INBOX"])
                    return f"received {row.name} into the inbox", None
                return self._answer(session, machine, names, queued), settings.delay

        message, delay = await asyncio.to_thread(handle)
        state.last_error = "" if not reception.failed else message
        if reception.failed:
            state.last_error_at = utcnow()
        bus = self.machines.bus
        bus.publish(ProgramReceived(machine.name, message))
        for job in queued:
            publish_job_queued(bus, **job)
        if delay is not None:
            # Wake the machine when the answer falls due (the request delay).
            asyncio.get_running_loop().call_later(delay + 0.05, state.wake.set)
            state.wake.set()

    def _version(self, session: Session, machine: MachineConfig, name: str) -> ProgramVersion | str:
        """The version a request for ``name`` sends to ``machine``, or why there is none
        (the report's line)."""
        try:
            # A rule builds the name from what the operator typed: only a program name
            # is looked up (docs/server.md#receiving-and-remote-request).
            library.check_program_name(name)
        except InputError:
            return f"{name} NOT A PROGRAM NAME"
        try:
            version = library.released_version(session, name)
            if version is None and not machine.released_only:
                version = library.get_version(session, name)
        except NotFound:
            return f"{name} NOT IN LIBRARY"
        if version is None:
            return f"{name} NOT RELEASED"
        return version

    def _check(self, machine: MachineConfig, names: list[str]) -> None:
        """Have the requested versions' program checks for ``machine`` stored (a dry run
        may take seconds; none runs inside the answer's write transaction)."""
        svc = self.services
        limits = checks.limits_of(svc, machine.name)
        with svc.reads() as session:
            found = [self._version(session, machine, name) for name in names]
            targets = [checks.Target.of(v) for v in found if isinstance(v, ProgramVersion)]
        for target in targets:
            checks.ensure(svc, target, limits)

    def _answer(
        self,
        session: Session,
        machine: MachineConfig,
        names: list[str],
        queued: list[dict[str, Any]],
    ) -> str:
        settings = self.settings
        due = utcnow() + timedelta(seconds=settings.delay)
        problems: list[str] = []  # one a program, for the audit trail
        report: list[str] = []  # the report's lines (a comment each, 60 characters at most)
        sent: list[str] = []
        failed_checks: list[dict[str, Any]] = []
        for name in names:
            version = self._version(session, machine, name)
            if isinstance(version, str):
                problems.append(version)
                report.append(version)
                continue
            try:
                # nobody at the control can override a check: no reason, ever
                policy.may_put_on(self.services, session, machine, JobKind.SEND, version, None)
            except policy.CheckFailed as refused:
                first = refused.check.first_error() or {}
                line = f"LINE {first.get('line', '?')}: {first.get('message', '')}"
                problems.append(f"{name} FAILED ITS CHECK, {line}")
                # the program, then the first error on a line or two of its own: a
                # control's comment is short, and the error is what the operator needs
                report.append(f"{name} FAILED ITS CHECK")
                report += textwrap.wrap(
                    line, requests.COMMENT_WIDTH, max_lines=2, placeholder=" ..."
                )
                failed_checks.append(
                    {
                        "program": name,
                        "version": version.number,
                        "sha256": version.sha256,
                        "errors": refused.check.errors,
                        "first": first,
                        "reason": str(refused),
                    }
                )
                continue
            except Conflict as refused:
                problems.append(f"{name} REFUSED: {refused}")
                report.append(problems[-1])
                continue
            job = jobs.enqueue(
                session,
                JobKind.SEND,
                machine.name,
                actor=f"request@{machine.name}",
                version=version,
                params={"request": True},
                not_before=due,
            )
            queued.append(
                {
                    "job_id": job.id,
                    "machine": machine.name,
                    "job_kind": JobKind.SEND.value,
                    "program": version.program.name,
                    "version": version.number,
                    "by": job.created_by,
                }
            )
            sent.append(name)
        audit.record(
            session,
            machine.name,
            "program.request",
            machine=machine.name,
            requested=names,
            sent=sent,
            refused=problems,
            failed_checks=failed_checks,
            result="ok" if not problems else "refused",
        )
        if problems and settings.reports != "none":
            self._report(session, machine, "REQUEST FAILED", report, due)
        elif sent and settings.reports == "all":
            self._report(session, machine, "REQUEST", [f"SENDING {n}" for n in sent], due)
        return f"request for {', '.join(names)}: {len(sent)} queued, {len(problems)} refused"

    def _report(
        self,
        session: Session,
        machine: MachineConfig,
        title: str,
        lines: list[str],
        due: datetime | None = None,
    ) -> None:
        number = self.settings.report_program
        digits = capabilities_of(machine).o_digits
        text = requests.report_program(number, title, lines, digits).decode("ascii")
        jobs.enqueue(
            session,
            JobKind.REPORT,
            machine.name,
            actor="server",
            not_before=due,
            params={"name": f"O{number:0{digits}d}.nc", "report": text},
        )
