"""Programs a control sends by itself (a punch): into the inbox, or answered as a remote
request (docs/server.md#receiving-and-remote-request).

The rules that tell a request from a program are :mod:`opendnc.server.core.requests`; this component
applies them to each reception a machine's task hands it, queues the requested programs after
the request delay (the released version; the newest where the machine takes drafts) and the
report programs the settings ask for, and wakes the machine when the answer falls due.

A requested program goes out under the decision a send from the API gets
(:func:`opendnc.server.actions.policy.authorize`), the version included: the released one
(the version rule every send follows; none released, the report says so), refused where the
machine's policy refuses it or where its program check for this machine finds errors (nobody
at the control can override them); the report says why, with the first error's line.
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
from opendnc.server.actions import policy
from opendnc.server.actions.base import Services
from opendnc.server.config.shop import MachineConfig
from opendnc.server.core import requests
from opendnc.server.core.errors import Conflict, NotFound
from opendnc.server.core.events import JobQueued, ProgramReceived
from opendnc.server.core.requests import RequestSettings
from opendnc.server.jobs import queue as jobs
from opendnc.server.kinds.connector import Reception
from opendnc.server.kinds.registry import capabilities_of
from opendnc.server.library import inbox
from opendnc.server.library import versions as library
from opendnc.server.library.checks import Checked
from opendnc.server.machines.state import Machines, MachineState
from opendnc.server.store import audit
from opendnc.server.store.models import JobKind, ProgramVersion, utcnow

__all__ = ["RemoteRequests"]

log = logging.getLogger(__name__)

Asked = policy.Decision | str
"""A requested program's prepared decision, or the report's line of why there is none."""


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
        self.services = services  # a send's rules: the actions layer's (policy.authorize)
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
        queued: list[JobQueued] = []  # the requested programs' jobs, announced once committed

        def handle() -> tuple[str, float | None]:
            names = None if reception.failed else requests.find_request(reception.data, settings)
            # decided before the write transaction (a check's dry run may take seconds)
            asked = self._prepare(machine, names) if names is not None else []
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
                return self._answer(session, machine, asked, queued), settings.delay

        message, delay = await asyncio.to_thread(handle)
        state.last_error = "" if not reception.failed else message
        if reception.failed:
            state.last_error_at = utcnow()
        bus = self.machines.bus
        bus.publish(ProgramReceived(machine.name, message))
        for event in queued:
            bus.publish(event)
        if delay is not None:
            # Wake the machine when the answer falls due (the request delay).
            asyncio.get_running_loop().call_later(delay + 0.05, state.wake.set)
            state.wake.set()

    def _prepare(self, machine: MachineConfig, names: list[str]) -> list[tuple[str, Asked]]:
        """Each requested name with its prepared decision, or why there is none (the
        report's line)."""
        asked: list[tuple[str, Asked]] = []
        for name in names:
            try:
                # A rule builds the name from what the operator typed: only a program name
                # is looked up (docs/server.md#receiving-and-remote-request).
                library.check_program_name(name)
            except InputError:
                asked.append((name, f"{name} NOT A PROGRAM NAME"))
                continue
            try:
                decision = policy.authorize(
                    self.services,
                    f"request@{machine.name}",
                    policy.Wanted(name),  # no number: the released one
                    [machine.name],
                    policy.Action.request(),
                )
            except NotFound:
                asked.append((name, f"{name} NOT IN LIBRARY"))
            except jobs.NotReleased:
                asked.append((name, f"{name} NOT RELEASED"))
            else:
                asked.append((name, decision))
        return asked

    def _answer(
        self,
        session: Session,
        machine: MachineConfig,
        asked: list[tuple[str, Asked]],
        queued: list[JobQueued],
    ) -> str:
        settings = self.settings
        due = utcnow() + timedelta(seconds=settings.delay)
        names = [name for name, _ in asked]
        problems: list[str] = []  # one a program, for the audit trail
        report: list[str] = []  # the report's lines (a comment each, 60 characters at most)
        sent: list[str] = []
        failed_checks: list[dict[str, Any]] = []
        for name, prepared in asked:
            if isinstance(prepared, str):
                problems.append(prepared)
                report.append(prepared)
                continue
            try:
                decision = prepared.confirm(session)
            except Conflict as stale:  # released anew meanwhile: the next request gets it
                problems.append(f"{name} REFUSED: {stale}")
                report.append(problems[-1])
                continue
            verdict = decision.verdict(machine.name)
            version = decision.row
            if verdict.refusal is policy.Refusal.CHECK_FAILED and verdict.check is not None:
                problem, lines, failed = _check_failure(name, decision, verdict, verdict.check)
                problems.append(problem)
                report += lines
                failed_checks.append(failed)
                continue
            if not verdict.allowed or version is None:
                problems.append(f"{name} REFUSED: {verdict.reason}")
                report.append(problems[-1])
                continue
            queued.append(_queue_send(session, machine, decision.actor, version, due))
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


def _check_failure(
    name: str, decision: policy.Decision, verdict: policy.Verdict, check: Checked
) -> tuple[str, list[str], dict[str, Any]]:
    """A program its check refused: the audit's problem, the report's lines and the audit's
    record of the failed check."""
    first = check.first_error() or {}
    line = f"LINE {first.get('line', '?')}: {first.get('message', '')}"
    # the program, then the first error on a line or two of its own: a control's comment
    # is short, and the error is what the operator needs
    lines = [f"{name} FAILED ITS CHECK"]
    lines += textwrap.wrap(line, requests.COMMENT_WIDTH, max_lines=2, placeholder=" ...")
    failed = {
        "program": name,
        "version": decision.version.number if decision.version else None,
        "sha256": decision.version.sha256 if decision.version else None,
        "errors": check.errors,
        "first": first,
        "reason": verdict.reason,
    }
    return f"{name} FAILED ITS CHECK, {line}", lines, failed


def _queue_send(
    session: Session,
    machine: MachineConfig,
    actor: str,
    version: ProgramVersion,
    due: datetime,
) -> JobQueued:
    """Queue the send of a requested ``version``, to start at ``due``; its event."""
    job = jobs.enqueue(
        session,
        JobKind.SEND,
        machine.name,
        actor=actor,
        version=version,
        params={"request": True},
        not_before=due,
    )
    # plain values now: the committed row's attributes may no longer be loaded
    return JobQueued(
        job.id,
        machine.name,
        JobKind.SEND,
        version.program.name,
        version.number,
        by=job.created_by,
    )
