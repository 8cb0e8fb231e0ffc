"""The pages' live streams (server-sent events): the machines' cards and a machine page's
DPRNT console (``/events/cards``), and the list pages' reload hints (``/events/lists``)."""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from datetime import UTC, tzinfo

from fastapi import APIRouter, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import StreamingResponse

from opendnc.errors import InputError
from opendnc.server import actions
from opendnc.server.actions.dprnt import DprntLineOut
from opendnc.server.core.errors import NotFound
from opendnc.server.core.events import (
    DprntLinePrinted,
    DprntStatus,
    Event,
    InboxChanged,
    JobEvent,
    JobFinished,
    JobProgress,
    MachineStatusChanged,
    NetshareChanged,
    ProgramChanged,
    ProgramReceived,
)
from opendnc.server.http.streams import event_stream_response
from opendnc.server.kinds.capabilities import capabilities_of
from opendnc.server.web import render
from opendnc.server.web.heartbeat import HEARTBEAT, Heartbeat, heartbeat_event
from opendnc.server.web.pages.base import Page, Viewing
from opendnc.server.web.pages.cards import CardCache

__all__ = ["CARD_INTERVAL", "CONSOLE_LINES", "LIST_EVENTS", "Console", "router"]

router = APIRouter(include_in_schema=False)
# A card changes at most this often on the overview (per machine), like the API's events.
CARD_INTERVAL = 0.5
# The DPRNT console keeps this many of a machine's newest lines (the CSV has more).
CONSOLE_LINES = 200


@router.get("/events/cards")
async def card_events(
    request: Request, page: Viewing, machine: str | None = None, dprnt: str | None = None
) -> StreamingResponse:
    """Server-sent events: ``cards`` with the HTML of every card that changed since the last
    one (each an out-of-band swap of ``#card-<machine>``), and ``jobs-<machine>`` when a job
    of that machine starts or ends (``machine``: just one).

    With ``machine`` and ``dprnt`` (the first and last id of the DPRNT lines its page shows,
    or ``0-0``), also ``dprnt-<machine>`` with the console's new lines and
    ``dprnt-status-<machine>`` with what the capture says about its link when that changes."""
    states = page.parts.machines.machines
    if machine is not None and machine not in states:
        raise NotFound(f"no machine named {machine!r}")
    shown = None
    if machine is not None and dprnt is not None and capabilities_of(states[machine].config).dprnt:
        shown = await run_in_threadpool(_shown_ids, page, machine, dprnt)
    zone = page.parts.calendar.zone
    source = Heartbeat(_Cards(page, machine, shown), zone)
    return event_stream_response(
        request,
        page.parts.machines.bus,
        source,
        interval=CARD_INTERVAL,
        who=page.who.name,
        beat=lambda: heartbeat_event(zone),
        keep_alive=HEARTBEAT,
    )


def _shown_ids(page: Page, machine: str, span: str) -> list[int]:
    # The ids the page shows: its span of the newest lines (none if it showed none).
    first, _, last = span.partition("-")
    if not (first.isdigit() and last.isdigit()):
        raise InputError("dprnt is FIRST-LAST (line ids)")
    lo, hi = int(first), int(last)
    if hi == 0:
        return []
    lines = actions.dprnt.recent_lines(page.svc, page.who, machine, CONSOLE_LINES)
    return [x.id for x in lines if lo <= x.id <= hi] or [hi]


class _Cards:
    """The live cards' stream: the cards that changed (one ``cards`` message), the machine
    pages told when a job starts or ends, and one machine page's DPRNT console."""

    def __init__(self, page: Page, only: str | None, dprnt_shown: list[int] | None) -> None:
        machines = page.parts.machines.machines
        self.page = page
        self.only = only
        self.template = render.environment().get_template("_card.html")
        self.watched = set(machines) if only is None else {only}
        self.cache = CardCache(stale=set(self.watched))
        self.zone = page.parts.calendar.zone
        self.sent: dict[str, str] = {}  # the HTML each card has in the browser now
        self.console = (
            Console(only, dprnt_shown, self.zone) if only and dprnt_shown is not None else None
        )
        # The capture's word as the stream starts (it may have changed since the page was drawn).
        self.capture_said: str | None = (
            page.parts.capture.status.get(only, "") if self.console and only is not None else None
        )
        self.pending: set[str] = set()
        self.job_changes: set[str] = set()
        self.new_lines = False

    async def snapshot(self, overflow: bool) -> bytes:
        # A fresh copy of every card: whatever changed between the page and this stream (or
        # was lost when the stream fell behind), and the console's lines printed since.
        self.pending = set(self.watched)
        if overflow:
            self.job_changes = set(self.watched)
        self.new_lines = self.console is not None
        return b""

    def take(self, event: Event) -> None:
        match event:
            case MachineStatusChanged(machine=machine) if machine in self.watched:
                self.pending.add(machine)
            case JobProgress(machine=machine) if machine in self.watched:
                self.pending.add(machine)
            case JobEvent(machine=machine) if machine in self.watched:
                self.pending.add(machine)  # queued, started or ended: the queue changed
                self.job_changes.add(machine)
                self.cache.stale.add(machine)
            case DprntLinePrinted(machine=machine) if machine in self.watched:
                self.new_lines = self.console is not None
            case DprntStatus(machine=machine, message=message) if machine in self.watched:
                self.capture_said = message if self.console else None
            case ProgramReceived(machine=machine) if machine in self.watched:
                self.pending.add(machine)

    async def flush(self) -> bytes:
        out = []
        if self.pending:
            names = sorted(self.pending)
            self.pending = set()
            out += await self._cards(names)
            out += [render.sse_event(f"jobs-{name}", "") for name in sorted(self.job_changes)]
            self.job_changes = set()
        console = self.console
        if console is not None and self.new_lines:
            self.new_lines = False
            html = await run_in_threadpool(self._console_update, console)
            if html:
                out.append(render.sse_event(f"dprnt-{console.machine}", html))
        if console is not None and self.capture_said is not None:
            said = f" · {render.text_escape(self.capture_said)}" if self.capture_said else ""
            self.capture_said = None
            out.append(render.sse_event(f"dprnt-status-{console.machine}", said))
        return b"".join(out)

    async def _cards(self, names: list[str]) -> list[bytes]:
        cards = await run_in_threadpool(self.cache.cards, self.page, names, self.zone)
        changed = []
        for c in cards:
            # a machine page's card shows the whole DPRNT line
            html = self.template.render(c=c, whole=self.only is not None, zone=self.zone)
            if self.sent.get(c.name) != html:  # a status poll that changed nothing
                self.sent[c.name] = html
                changed.append(render.card_oob(c.name, html))
                if self.only is not None:
                    # the queue table's progress says what the card says
                    changed.append(render.queue_progress_oob(c))
        # One message for every card that changed: the browser parses and swaps them in one
        # go instead of running a swap per card.
        return [render.sse_event("cards", "".join(changed))] if changed else []

    def _console_update(self, console: Console) -> str:
        page = self.page
        return console.update(
            actions.dprnt.recent_lines(page.svc, page.who, console.machine, CONSOLE_LINES)
        )


class Console:
    """What one machine page's DPRNT console shows, and the HTML that brings it up to date.

    The page names the lines it was drawn with (``dprnt=FIRST-LAST`` ids); each update adds
    the lines printed since (swapped in at the end of the list) and removes, by id, those that
    fell out of the newest :data:`CONSOLE_LINES` (out-of-band deletes), so the page never
    holds more than that and never shows a line twice, whenever the stream (re)connects.
    """

    def __init__(self, machine: str, shown: list[int], zone: tzinfo = UTC) -> None:
        self.machine = machine
        self.shown: deque[int] = deque(sorted(shown))
        self.zone = zone

    def update(self, recent: Sequence[DprntLineOut]) -> str:
        """The HTML for the machine's ``recent`` lines (its newest, oldest first): any
        printed before them would fall out of the console anyway."""
        last = self.shown[-1] if self.shown else 0
        lines = [x for x in recent if x.id > last]
        if not lines:
            return ""
        gone = []
        for line in lines:
            self.shown.append(line.id)
        while len(self.shown) > CONSOLE_LINES:
            gone.append(self.shown.popleft())
        first = self.shown[0]
        shown = [x.model_dump(mode="json") for x in lines if x.id >= first]
        return render.render("_dprnt.html", lines=shown, gone=gone, zone=self.zone)


# Which bus events change which list page (the watcher's and the routes' ``program``, a
# reception's ``received`` or ``netshare``, an accept's or discard's ``inbox``).
LIST_EVENTS: dict[str, tuple[type[Event], ...]] = {
    "inbox": (ProgramReceived, NetshareChanged, InboxChanged),
    "library": (ProgramChanged,),
    # what the net share did, a release (which changes how its files compare), and a job's
    # end (a send to a Haas NGC writes into its share: the page's "Replace" button)
    "netshare": (NetshareChanged, ProgramChanged, JobFinished),
}


@router.get("/events/lists")
async def list_events(request: Request, page: Viewing, topic: str) -> StreamingResponse:
    """Server-sent events named ``topic`` (``inbox``, ``library`` or ``netshare``), no data,
    at most every :data:`CARD_INTERVAL` while that list changes: the page reloads the list on
    each."""
    if topic not in LIST_EVENTS:
        raise InputError(f"topic {topic[:20]!r}: inbox, library or netshare")
    zone = page.parts.calendar.zone
    source = Heartbeat(_ListChanges(topic), zone)
    return event_stream_response(
        request,
        page.parts.machines.bus,
        source,
        interval=CARD_INTERVAL,
        who=page.who.name,
        beat=lambda: heartbeat_event(zone),
        keep_alive=HEARTBEAT,
    )


class _ListChanges:
    """A list page's stream: one event named after its topic when the list may have changed."""

    def __init__(self, topic: str) -> None:
        self.topic = topic
        self.kinds = LIST_EVENTS[topic]
        self.dirty = False

    async def snapshot(self, overflow: bool) -> bytes:
        self.dirty = True  # whatever changed between the page and this stream, or was lost
        return b""

    def take(self, event: Event) -> None:
        self.dirty = self.dirty or isinstance(event, self.kinds)

    async def flush(self) -> bytes:
        if not self.dirty:
            return b""
        self.dirty = False
        return render.sse_event(self.topic, "")
