"""The dashboard's pages: server-rendered HTML, a thin adapter over the actions layer.

Reads render a page (or, for htmx, a fragment); writes check the session's CSRF token, call
the action the API route calls (:mod:`opendnc.server.actions`, which checks the role and the
machine's policy), and answer with the fragment to swap in. A refused write answers with its
status (400, 403, 404, 409, 503) and a message that htmx puts in the page's alert area (see
``__init__``). What a role cannot do is not shown to it, and the action refuses it anyway.

Routes are plain functions where they touch the database (FastAPI runs them in its thread
pool, so the machines' event loop never waits for a query).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta, tzinfo
from typing import Annotated, Any, TypeVar
from urllib.parse import quote

from fastapi import APIRouter, Depends, Form, Path, Query, Request, UploadFile
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import HTMLResponse, RedirectResponse, Response, StreamingResponse
from sqlalchemy import select
from sqlalchemy.orm import Session, joinedload, sessionmaker

from opendnc.errors import InputError
from opendnc.server import actions
from opendnc.server.access import auth
from opendnc.server.access.refusals import Refusals
from opendnc.server.access.throttle import DEVICE_COOKIE
from opendnc.server.actions.models import MAX_ID, AuditOut, Content, JobOut, JobRequest
from opendnc.server.core.components import core_of
from opendnc.server.core.errors import (
    Conflict,
    Forbidden,
    NotFound,
    TooLarge,
    TooManyRequests,
    Unauthorized,
    Unavailable,
)
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
from opendnc.server.http import deps
from opendnc.server.http import dprnt as dprnt_api
from opendnc.server.http.downloads import stored_response
from opendnc.server.http.streams import event_stream_response
from opendnc.server.jobs import queue as jobs
from opendnc.server.kinds.capabilities import capabilities_of
from opendnc.server.library.versions import MAX_PROGRAM_BYTES
from opendnc.server.machines.state import Machines
from opendnc.server.machines.timeline import Timeline
from opendnc.server.store.models import (
    Job,
    JobKind,
    JobState,
    Program,
    ProgramState,
    ProgramVersion,
    ReceivedState,
    Role,
)
from opendnc.server.web import listing, render
from opendnc.server.web import session as web_session
from opendnc.server.web.heartbeat import HEARTBEAT, Heartbeat, heartbeat_event

__all__ = ["LoginNeeded", "Page", "router"]

T = TypeVar("T")
router = APIRouter(include_in_schema=False)
# A card changes at most this often on the overview (per machine), like the API's events.
CARD_INTERVAL = 0.5
FINISHED = [JobState.DONE, JobState.FAILED, JobState.CANCELLED, JobState.INTERRUPTED]
ROLES = [r.name.lower() for r in Role]
# The editor takes programs up to this size (a form field holds at most 1 MiB, and a browser
# sends every line end as CR LF); a larger one is edited offline and uploaded.
MAX_EDIT_BYTES = 512 * 1024
MAX_EDIT_CHARS = 1024 * 1024
TIMELINE_HOURS = 4
WALL_SECONDS = 15  # each page of the wall display shows this long
# The DPRNT console keeps this many of a machine's newest lines (the CSV has more).
CONSOLE_LINES = 200


class LoginNeeded(Exception):
    """No valid session: pages redirect to the login, htmx requests are told to."""

    def __init__(self, next_url: str) -> None:
        super().__init__(next_url)
        self.next_url = next_url


@dataclass(frozen=True)
class Page:
    """Who is looking, and what the page needs to write back safely."""

    who: auth.Principal
    key: str
    csrf: str

    def can(self, role: str) -> bool:
        """True if the user's role includes ``role`` (what the page offers)."""
        return self.who.can(Role.parse(role))


def _sessions(request: Request) -> sessionmaker[Session]:
    return deps.database(request).sessions


def _supervisor(request: Request) -> Machines:
    return deps.machines(request)


def _svc(request: Request) -> actions.Services:
    return core_of(request.app).get(actions.Services)


def _page(request: Request) -> Page:
    try:
        svc = _svc(request)
        who, key = web_session.principal(
            svc.reads, svc.sessions, deps.key_use(request), svc.keys, request
        )
    except Unauthorized:
        target = request.url.path + (f"?{request.url.query}" if request.url.query else "")
        raise LoginNeeded(target) from None
    return Page(who, key, web_session.csrf_token(key))


async def _write_page(request: Request) -> Page:
    page = await run_in_threadpool(_page, request)
    token = None
    if web_session.CSRF_HEADER not in request.headers:
        form = await request.form()  # cached: the route's own Form fields read it again
        value = form.get(web_session.CSRF_FIELD)
        token = value if isinstance(value, str) else None
    web_session.check_csrf(request, page.key, token)
    return page


Viewing = Annotated[Page, Depends(_page)]
Writing = Annotated[Page, Depends(_write_page)]
JobId = Annotated[int, Path(ge=1, le=MAX_ID)]
ReceivedId = Annotated[int, Path(ge=1, le=MAX_ID)]
VersionPath = Annotated[int, Path(ge=1, le=MAX_ID)]
VersionNumber = Annotated[int, Query(ge=1, le=MAX_ID)]
Short = Annotated[str, Query(max_length=64)]
# Form fields: a program name, a path on a control, a program line or version
ProgramField = Annotated[str, Form(max_length=100)]
ControlPath = Annotated[str, Form(max_length=255)]
NumberField = Annotated[int | None, Form(ge=1, le=MAX_ID)]


def _read(request: Request, work: Callable[[Session], T]) -> T:
    # Pages and live cards only read: on SQLite they need not queue behind the write lock
    # (docs/server.md#event-loop-stalls).
    reads = deps.database(request).reads
    with reads() as session:
        return work(session)


def _zone(request: Request) -> tzinfo:
    # the shop's clock ([server] timezone): every time a person reads is on it
    return _supervisor(request).config.calendar.zone


def _html(template: str, page: Page | None, request: Request, **context: Any) -> HTMLResponse:
    calendar = _supervisor(request).config.calendar
    context.setdefault("zone", calendar.zone)
    context.setdefault("zone_name", calendar.zone_name)
    context.setdefault("zone_label", render.zone_label(None, calendar.zone))
    return HTMLResponse(
        render.render(template, page=page, path=request.url.path, roles=ROLES, **context)
    )


def _is_htmx(request: Request) -> bool:
    return request.headers.get("HX-Request") == "true"


# -- login --------------------------------------------------------------------------------


@router.get("/login")
def login_form(request: Request, next: str = "/") -> Response:
    """The login page (with the form's CSRF token, web_session.login_token)."""
    return _login_page(request, next, "", "", 200)


def _login_page(request: Request, next: str, error: str, username: str, status: int) -> Response:
    token, new = web_session.login_token(request)
    page = _html(
        "login.html",
        None,
        request,
        next=_safe_next(next),
        error=error,
        username=username,
        login_csrf=token,
    )
    page.status_code = status
    if new:
        web_session.set_login_cookie(page, token, secure=request.url.scheme == "https")
    return page


def _safe_next(target: str) -> str:
    # Only paths on this server: never an open redirect to another site.
    return target if target.startswith("/") and not target.startswith("//") else "/"


@router.post("/login", response_model=None)
def login(
    request: Request,
    username: Annotated[str, Form()],
    password: Annotated[str, Form()],
    next: Annotated[str, Form()] = "/",
    csrf: Annotated[str, Form(max_length=100)] = "",
) -> Response:
    """Check the form's token and the password, start a session, go where the user was
    heading (docs/server.md#throttling)."""
    response = RedirectResponse(_safe_next(next), status_code=303)
    address = request.client.host if request.client else "?"
    try:
        web_session.check_login_csrf(request, csrf)
        web_session.log_in(
            _sessions(request),
            _svc(request).guard,
            core_of(request.app).get(Refusals),
            response,
            username,
            password,
            secure=request.url.scheme == "https",
            address=address,
            device=request.cookies.get(DEVICE_COOKIE),
        )
    except Forbidden as exc:
        refusals = core_of(request.app).get(Refusals)
        refusals.note(actor=username, via="web", address=address, name=username, error=str(exc))
        return _login_page(request, next, str(exc), username, 403)
    except TooManyRequests as exc:
        page = _login_page(request, next, str(exc), username, 429)
        page.headers["Retry-After"] = str(exc.retry_after)
        return page
    except (Unauthorized, InputError) as exc:
        return _login_page(request, next, str(exc), username, 401)
    return response


@router.post("/logout")
def logout(request: Request, page: Writing) -> RedirectResponse:
    """End the session."""
    response = RedirectResponse("/login", status_code=303)
    web_session.log_out(_sessions(request), _svc(request).keys, request, response)
    return response


# -- shop overview ------------------------------------------------------------------------


def _cards(request: Request, names: list[str] | None = None) -> list[render.Card]:
    supervisor = _supervisor(request)
    states = supervisor.machines
    wanted = names if names is not None else list(states)

    def load(session: Session) -> tuple[dict[str, int], dict[int, str], dict[str, render.LastJob]]:
        queued = jobs.queue_lengths(session)
        running = [states[name].job_id for name in wanted]
        labels = _job_labels(session, [i for i in running if i is not None])
        return queued, labels, _last_jobs(session, wanted)

    queued, labels, last = _read(request, load)
    zone = _zone(request)
    out = []
    for name in wanted:
        job_id = states[name].job_id
        label = labels.get(job_id, "") if job_id is not None else ""
        out.append(
            render.card(
                render.Seen.of(states[name], label),
                queued=queued.get(name, 0),
                last_job=last.get(name),
                zone=zone,
            )
        )
    return out


def _last_jobs(session: Session, names: list[str]) -> dict[str, render.LastJob]:
    # each machine's last finished job, as its card tells it (one query for all)
    found = jobs.last_finished(session, names)
    return {
        name: render.LastJob(_label(job), job.state.value, job.finished, job.error)
        for name, job in found.items()
    }


def _label(job: Job) -> str:
    if job.version is not None:
        return f"{job.kind.value} {job.version.program.name} v{job.version.number}"
    # a report names its program; a receive, delete or put its path on the control
    return f"{job.kind.value} {job.params.get('name') or job.params.get('path') or ''}".strip()


def _job_labels(session: Session, ids: list[int]) -> dict[int, str]:
    # One query for the labels of many jobs (two hundred start at once when a program goes
    # to every machine), not three per job; a job gone from the table gets none.
    if not ids:
        return {}
    stmt = (
        select(Job)
        .where(Job.id.in_(ids))
        .options(joinedload(Job.version).joinedload(ProgramVersion.program))
    )
    found = {job.id: _label(job) for job in session.scalars(stmt).unique()}
    return {i: found.get(i, "") for i in ids}


@router.get("/")
def overview(request: Request, page: Viewing) -> HTMLResponse:
    """A card per machine, kept live by server-sent events."""
    return _html("overview.html", page, request, **_floor(request))


def _floor(request: Request) -> dict[str, Any]:
    # what the overview and the wall display show: the cards, how many are in each state,
    # the machines in alarm, and the zone the times are on
    cards = _cards(request)
    counts = {state: sum(1 for c in cards if c.state == state) for state in render.STATES}
    in_alarm = [c for c in cards if c.state == "alarm"]
    return {"cards": cards, "counts": counts, "in_alarm": in_alarm}


@router.get("/wall")
def wall(
    request: Request,
    page: Viewing,
    every: Annotated[int, Query(ge=3, le=600)] = WALL_SECONDS,
) -> HTMLResponse:
    """The floor for a screen on the wall: large type, no controls, the pages of a shop
    larger than the screen shown in turn (``every`` seconds each)."""
    return _html("wall.html", page, request, every=every, **_floor(request))


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
    states = _supervisor(request).machines
    if machine is not None and machine not in states:
        raise NotFound(f"no machine named {machine!r}")
    shown = None
    if machine is not None and dprnt is not None and capabilities_of(states[machine].config).dprnt:
        shown = _shown_ids(request, machine, dprnt)
    zone = _zone(request)
    source = Heartbeat(_Cards(request, machine, shown), zone)
    bus = _supervisor(request).bus
    return event_stream_response(
        request,
        bus,
        source,
        interval=CARD_INTERVAL,
        who=page.who.name,
        beat=lambda: heartbeat_event(zone),
        keep_alive=HEARTBEAT,
    )


def _shown_ids(request: Request, machine: str, span: str) -> list[int]:
    # The ids the page shows: its span of the newest lines (none if it showed none).
    first, _, last = span.partition("-")
    if not (first.isdigit() and last.isdigit()):
        raise InputError("dprnt is FIRST-LAST (line ids)")
    lo, hi = int(first), int(last)
    if hi == 0:
        return []

    def load(session: Session) -> list[int]:
        lines = dprnt_api.recent_lines(session, machine, CONSOLE_LINES)
        return [x["id"] for x in lines if lo <= x["id"] <= hi] or [hi]

    return _read(request, load)


class _Cards:
    """The live cards' stream: the cards that changed (one ``cards`` message), the machine
    pages told when a job starts or ends, and one machine page's DPRNT console."""

    def __init__(self, request: Request, only: str | None, dprnt_shown: list[int] | None) -> None:
        supervisor = _supervisor(request)
        self.request = request
        self.only = only
        self.template = render.environment().get_template("_card.html")
        self.labels: dict[int, str] = {}
        # each machine's last finished job: read again only when one of its jobs ends
        self.last: dict[str, render.LastJob] = {}
        self.last_stale: set[str] = set(supervisor.machines) if only is None else {only}
        self.zone = _zone(request)
        self.watched = set(supervisor.machines) if only is None else {only}
        self.sent: dict[str, str] = {}  # the HTML each card has in the browser now
        self.console = (
            _Console(only, dprnt_shown, self.zone) if only and dprnt_shown is not None else None
        )
        capture = deps.dprnt(request)
        # The capture's word as the stream starts (it may have changed since the page was drawn).
        self.capture_said: str | None = (
            capture.status.get(only, "") if self.console and only is not None else None
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
                self.last_stale.add(machine)
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
            cards = await run_in_threadpool(_cards_cached, self.request, names, self)
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
            if changed:
                # One message for every card that changed: the browser parses and swaps
                # them in one go instead of running a swap per card.
                out.append(render.sse_event("cards", "".join(changed)))
            out += [render.sse_event(f"jobs-{name}", "") for name in sorted(self.job_changes)]
            self.job_changes = set()
        console = self.console
        if console is not None and self.new_lines:
            self.new_lines = False
            html = await run_in_threadpool(_read, self.request, console.update)
            if html:
                out.append(render.sse_event(f"dprnt-{console.machine}", html))
        if console is not None and self.capture_said is not None:
            said = f" · {render.text_escape(self.capture_said)}" if self.capture_said else ""
            self.capture_said = None
            out.append(render.sse_event(f"dprnt-status-{console.machine}", said))
        return b"".join(out)


class _Console:
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

    def update(self, session: Session) -> str:
        last = self.shown[-1] if self.shown else 0
        # the newest lines: any printed before them would fall out of the console anyway
        recent = dprnt_api.recent_lines(session, self.machine, CONSOLE_LINES)
        lines = [x for x in recent if x["id"] > last]
        if not lines:
            return ""
        gone = []
        for line in lines:
            self.shown.append(line["id"])
        while len(self.shown) > CONSOLE_LINES:
            gone.append(self.shown.popleft())
        first = self.shown[0]
        shown = [x for x in lines if x["id"] >= first]
        return render.render("_dprnt.html", lines=shown, gone=gone, zone=self.zone)


def _cards_cached(request: Request, names: list[str], stream: _Cards) -> list[render.Card]:
    # The labels of running jobs do not change: look each up once per stream; a machine's
    # last finished job only when one of its jobs ended.
    states = _supervisor(request).machines
    labels, last = stream.labels, stream.last

    def load(session: Session) -> dict[str, int]:
        new = [states[n].job_id for n in names if states[n].job_id not in labels]
        labels.update(_job_labels(session, [i for i in new if i is not None]))
        stale = [n for n in names if n in stream.last_stale]
        if stale:
            for n in stale:
                last.pop(n, None)
            last.update(_last_jobs(session, stale))
            stream.last_stale.difference_update(stale)
        return jobs.queue_lengths(session)

    queued = _read(request, load)
    out = []
    for name in names:
        job_id = states[name].job_id
        label = labels.get(job_id, "") if job_id is not None else ""
        out.append(
            render.card(
                render.Seen.of(states[name], label),
                queued=queued.get(name, 0),
                last_job=last.get(name),
                zone=stream.zone,
            )
        )
    return out


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
    zone = _zone(request)
    source = Heartbeat(_ListChanges(topic), zone)
    bus = _supervisor(request).bus
    return event_stream_response(
        request,
        bus,
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


# -- machine page -------------------------------------------------------------------------


def _machine_context(request: Request, page: Page, name: str) -> dict[str, Any]:
    svc = _svc(request)
    state = svc.machine(name)

    def rows(states: list[JobState], limit: int = 200) -> list[dict[str, Any]]:
        found = actions.queue.list_jobs(svc, page.who, machine=name, states=states, limit=limit)
        return [_job_row(j) for j in found]

    context: dict[str, Any] = {
        "queue": rows([JobState.QUEUED]),
        "running": rows([JobState.RUNNING]),
        "history": rows(FINISHED, 50),
    }
    live = state.as_json()
    caps = capabilities_of(state.config)
    context["machine"] = live
    timeline: Timeline = deps.timeline(request)
    timeline.note(name, state.reading(), online=state.online)
    now = datetime.now(UTC)
    context["timeline"] = timeline.segments(name, hours=TIMELINE_HOURS, now=now)
    context["timeline_ticks"] = render.axis_ticks(
        now - timedelta(hours=TIMELINE_HOURS), now, _zone(request)
    )
    context["timeline_hours"] = TIMELINE_HOURS
    context["timeline_days"] = timeline.retention.total_seconds() / 86400
    context["console_lines"] = CONSOLE_LINES
    context["dripfeed"] = caps.dripfeed
    context["released"] = _read(request, _released_names) if caps.dripfeed else []
    context["has_files"] = caps.file_browser
    context["dprnt"] = None
    if caps.dprnt:
        lines = _read(request, lambda s: dprnt_api.recent_lines(s, name, CONSOLE_LINES))
        capture = deps.dprnt(request)
        context["dprnt"] = {
            "lines": lines,
            "span": f"{lines[0]['id']}-{lines[-1]['id']}" if lines else "0-0",
            "status": capture.status.get(name, "") if capture is not None else "",
        }
    last = _read(request, lambda s: _last_jobs(s, [name]))
    context["card"] = render.card(
        render.Seen.of(state),
        queued=len(context["queue"]),
        last_job=last.get(name),
        zone=_zone(request),
    )
    return context


def _released_names(session: Session) -> list[str]:
    # what a drip-feed machine is offered: programs with a released version
    stmt = (
        select(Program.name)
        .join(ProgramVersion)
        .where(ProgramVersion.state == ProgramState.RELEASED)
        .distinct()
        .order_by(Program.name)
        .limit(2000)
    )
    return list(session.scalars(stmt))


def _job_row(job: JobOut) -> dict[str, Any]:
    row = job.model_dump(mode="json")
    if job.program is None:  # a report names its program, a receive or delete its path
        row["program"] = str(job.params.get("name") or job.params.get("path") or "")
    return row


@router.get("/machines/{name}")
def machine_page(request: Request, name: str, page: Viewing) -> HTMLResponse:
    """The machine's status, queue and job history."""
    return _html("machine.html", page, request, **_machine_context(request, page, name))


@router.get("/machines/{name}/dprnt.csv")
def machine_dprnt_csv(request: Request, name: str, page: Viewing) -> Response:
    """The machine's newest DPRNT lines (up to the API's limit) as CSV, oldest first."""
    if name not in _supervisor(request).machines:
        raise NotFound(f"no machine named {name!r}")
    lines = _read(request, lambda s: dprnt_api.recent_lines(s, name, dprnt_api.MAX_LIMIT))
    return dprnt_api.csv_response(name, lines)


@router.get("/machines/{name}/jobs")
def machine_jobs(request: Request, name: str, page: Viewing) -> HTMLResponse:
    """The queue and history fragment (refreshed by the page while jobs run)."""
    return _jobs_fragment(request, page, name)


def _jobs_fragment(request: Request, page: Page, machine: str) -> HTMLResponse:
    """The machine's queue and history: what the page shows again after a job action."""
    return _html("_jobs.html", page, request, **_machine_context(request, page, machine))


@router.post("/jobs/{job_id}/cancel")
def cancel_job(request: Request, job_id: JobId, page: Writing) -> HTMLResponse:
    """Cancel a queued job, or ask a running one to stop (at its next safe point)."""
    return _jobs_fragment(
        request, page, actions.queue.cancel_job(_svc(request), page.who, job_id).machine
    )


@router.post("/jobs/{job_id}/move")
def move_job(
    request: Request, job_id: JobId, page: Writing, index: Annotated[int, Form(ge=0, le=MAX_ID)]
) -> HTMLResponse:
    """Put a queued job at ``index`` in its queue."""
    return _jobs_fragment(
        request, page, actions.queue.move_job(_svc(request), page.who, job_id, index).machine
    )


@router.post("/jobs/{job_id}/retry")
def retry_job(
    request: Request, job_id: JobId, page: Writing, from_line: NumberField = None
) -> HTMLResponse:
    """Queue a failed, interrupted or cancelled job again (a drip-feed from a line, which
    programmers restart: it runs the machine)."""
    return _jobs_fragment(
        request, page, actions.queue.retry_job(_svc(request), page.who, job_id, from_line).machine
    )


@router.post("/machines/{name}/dripfeed")
def start_dripfeed(
    request: Request,
    name: str,
    page: Writing,
    program: ProgramField,
    from_line: NumberField = None,
) -> HTMLResponse:
    """Drip-feed the released version of ``program`` to the machine (programmers; the page
    asks first, since the machine runs it as it arrives)."""
    order = JobRequest(
        kind=JobKind.DRIPFEED, program=program.strip(), machines=[name], from_line=from_line
    )
    return _jobs_fragment(
        request, page, actions.queue.create_jobs(_svc(request), page.who, order)[0].machine
    )


# -- file browser (controls with one) -------------------------------------------------------


@router.get("/machines/{name}/files")
async def machine_files_page(
    request: Request, name: str, page: Viewing, path: str | None = None, note: str = ""
) -> HTMLResponse:
    """A folder of the control (a fragment the machine page loads), read on the machine's
    own link."""
    folder = await actions.files.list_folder(_svc(request), page.who, name, path)
    return _html("_files.html", page, request, note=note, **folder.model_dump(mode="json"))


@router.get("/machines/{name}/files/download")
async def machine_file_download(request: Request, name: str, path: str, page: Viewing) -> Response:
    """One file of the control, as a download."""
    return _download(await actions.files.read_file(_svc(request), page.who, name, path))


def _download(content: Content) -> Response:
    """``content`` as a file to save under its own name, with its SHA-256 beside it."""
    return Response(
        content.data,
        media_type="application/octet-stream",
        headers={
            "Content-Disposition": f'attachment; filename="{content.name}"',
            "X-Content-SHA256": content.sha256,
        },
    )


async def _after_file_job(request: Request, page: Page, job: JobOut, folder: str) -> HTMLResponse:
    # The folder as it is once the job ran: the listing waits behind the machine's queue.
    note = f"job {job.id}: {job.kind.value} {job.params.get('path', '')} queued"
    if job.params.get("into_library"):
        note += " (into the library as a new draft version)"
    try:
        return await machine_files_page(request, job.machine, page, folder, note)
    except (Conflict, Unavailable) as exc:
        # the job is queued whatever the listing says (a control without a browser, offline)
        note = f"{note}; {exc}"
        return _html("_files.html", page, request, note=note, machine=job.machine, entries=[])


@router.post("/machines/{name}/files/upload")
async def machine_file_upload(
    request: Request,
    name: str,
    page: Writing,
    file: UploadFile,
    folder: ControlPath,
) -> HTMLResponse:
    """Put a file from the person's computer on the control: a library draft first, then a
    ``put_file`` job under the machine's policy (programmers)."""
    actions.policy.may_queue(page.who, JobKind.PUT_FILE)  # before the file is read
    data = await _read_upload(file)
    job = await run_in_threadpool(
        actions.files.put_file, _svc(request), page.who, name, folder, file.filename or "", data
    )
    return await _after_file_job(request, page, job, folder)


@router.post("/machines/{name}/files/delete")
async def machine_file_delete(
    request: Request, name: str, page: Writing, path: ControlPath
) -> HTMLResponse:
    """Delete a file on the control: a ``delete`` job (programmers; the page asks first)."""
    return await _file_job(request, page, actions.files.delete_file, name, path)


@router.post("/machines/{name}/files/receive")
async def machine_file_receive(
    request: Request, name: str, page: Writing, path: ControlPath
) -> HTMLResponse:
    """Bring a file of the control to the inbox under its own name: a ``receive`` job."""
    return await _file_job(request, page, actions.files.receive_file, name, path)


async def _file_job(
    request: Request,
    page: Page,
    action: Callable[[actions.Services, auth.Principal, str, str], JobOut],
    machine: str,
    path: str,
) -> HTMLResponse:
    """Queue ``action``'s job on the file ``path`` of ``machine``, then show its folder."""
    job = await run_in_threadpool(action, _svc(request), page.who, machine, path)
    return await _after_file_job(request, page, job, path.replace("\\", "/").rsplit("/", 1)[0])


@router.post("/machines/{name}/files/take-back")
async def machine_file_take_back(
    request: Request, name: str, page: Writing, path: Annotated[str, Form(max_length=255)]
) -> HTMLResponse:
    """Take a file of the control back into the library as a new draft version of the
    program of its name: a ``receive`` job (programmers)."""
    job = await run_in_threadpool(actions.files.take_back, _svc(request), page.who, name, path)
    return await _after_file_job(request, page, job, path.replace("\\", "/").rsplit("/", 1)[0])


async def _read_upload(file: UploadFile) -> bytes:
    data = await file.read(MAX_PROGRAM_BYTES + 1)
    if len(data) > MAX_PROGRAM_BYTES:
        raise TooLarge("the upload is larger than the server takes")
    return data


# -- program library ----------------------------------------------------------------------


@router.get("/library")
def library_page(
    request: Request,
    page: Viewing,
    q: Annotated[str, Query(max_length=255)] = "",
    text: Annotated[str, Query(max_length=255)] = "",
) -> HTMLResponse:
    """Programs, searchable by name or title and in their text."""
    found = actions.library.list_programs(_svc(request), page.who, q, text)
    programs = [p.model_dump(mode="json") for p in found]
    template = "_programs.html" if _is_htmx(request) else "library.html"
    return _html(template, page, request, programs=programs, q=q, text=text)


@router.get("/library/{name}")
def program_page(
    request: Request,
    name: str,
    page: Viewing,
    v: VersionNumber | None = None,
    a: VersionNumber | None = None,
    b: VersionNumber | None = None,
    line: Annotated[int | None, Query(ge=1, le=MAX_ID)] = None,
) -> HTMLResponse:
    """One program: versions, the text of one of them highlighted (from ``line``), its
    preview, or a diff of two."""
    svc = _svc(request)
    program = actions.library.get_program(svc, page.who, name)
    shown = actions.library.program_content(svc, page.who, name, v)
    number = v if v is not None else program.versions[-1].number
    version = next(x for x in program.versions if x.number == number)
    text = render.program_text(shown.data)
    released = [x.number for x in program.versions if x.state is ProgramState.RELEASED]
    check = actions.checks.version_check(svc, page.who, name, number)
    context: dict[str, Any] = {
        "program": program.model_dump(mode="json"),
        "shown": version.model_dump(mode="json"),
        "released": released[-1] if released else None,
        "listing": listing.window(text, name=name, size=len(shown.data), line=line),
        "check": check.model_dump(mode="json"),
        "diff": None,
    }
    if a is not None and b is not None:
        old = actions.library.program_content(svc, page.who, name, a).data
        new = actions.library.program_content(svc, page.who, name, b).data
        context["diff"] = render.side_by_side(render.program_text(old), render.program_text(new))
        context["a"], context["b"] = a, b
    machines = [
        {"name": m.config.name, "released_only": m.config.released_only, "online": m.online}
        for m in _supervisor(request).machines.values()
    ]
    return _html("program.html", page, request, machines=machines, **context)


@router.get("/library/{name}/versions/{number}/download")
def download_version(request: Request, name: str, number: VersionPath, page: Viewing) -> Response:
    """The bytes of one version, as a file."""
    svc = _svc(request)
    stored = actions.library.program_stored(svc, page.who, name, number)
    response = stored_response(svc.reads, stored)  # streamed as the browser reads it
    response.headers["Content-Disposition"] = f'attachment; filename="{stored.name}"'
    return response


def _override(override: str | None, reason: str) -> str | None:
    # the form's "override" box: ticked, its reason (blank is refused by the rules); else none
    return reason if override else None


Override = Annotated[str | None, Form(max_length=10)]
Reason = Annotated[str, Form(max_length=1000)]


@router.post("/library/{name}/versions/{number}/release")
def release_version(
    request: Request,
    name: str,
    number: VersionPath,
    page: Writing,
    override: Override = None,
    reason: Reason = "",
) -> Response:
    """Release a version (approvers); a program check's errors need the override box and a
    reason."""
    actions.library.release_version(
        _svc(request), page.who, name, number, _override(override, reason)
    )
    return _redirect(request, f"/library/{quote(name)}?v={number}")


@router.get("/library/{name}/checks")
def machine_checks(
    request: Request, name: str, page: Viewing, version: VersionNumber | None = None
) -> HTMLResponse:
    """The send form's list: a version's program check on each machine (a fragment)."""
    names = [m.config.name for m in _supervisor(request).machines.values()]
    found = actions.checks.machine_checks(_svc(request), page.who, name, version, names)
    rows = [c.model_dump(mode="json") for c in found]
    return _html("_machine_checks.html", page, request, checks=rows, program=name)


@router.get("/library/{name}/versions/{number}/edit")
def edit_page(request: Request, name: str, number: VersionPath, page: Viewing) -> HTMLResponse:
    """The editor: version ``number`` as text to change and save as a new draft
    (programmers)."""
    actions.library.may_upload(page.who)
    svc = _svc(request)
    program = actions.library.get_program(svc, page.who, name)
    content = actions.library.program_content(svc, page.who, name, number)
    if len(content.data) > MAX_EDIT_BYTES:
        raise InputError(
            f"{name} v{number} is {render.human_size(len(content.data))}: the browser's editor "
            f"takes {render.human_size(MAX_EDIT_BYTES)}; download it, edit it and upload it"
        )
    version = next(x for x in program.versions if x.number == number)
    return _html(
        "editor.html",
        page,
        request,
        program=program.model_dump(mode="json"),
        shown=version.model_dump(mode="json"),
        text=render.program_text(content.data),
        language=render.language_of(name, content.data),
    )


@router.post("/library/{name}/versions/{number}/edit")
def save_edit(
    request: Request,
    name: str,
    number: VersionPath,
    page: Writing,
    text: Annotated[str, Form(max_length=MAX_EDIT_CHARS)],
    comment: Annotated[str, Form(max_length=1000)] = "",
) -> Response:
    """Save the edited text as a new draft with its comment (programmers); the program page
    of the new version shows its check."""
    saved = actions.library.save_edit(_svc(request), page.who, name, number, text, comment=comment)
    return _redirect(request, f"/library/{quote(name)}?v={saved.number}#check")


@router.post("/library/{name}/lock")
def lock_program(
    request: Request, name: str, page: Writing, locked: Annotated[bool, Form()]
) -> Response:
    """Lock or unlock a program (approvers)."""
    actions.library.set_locked(_svc(request), page.who, name, locked)
    return _redirect(request, f"/library/{quote(name)}")


@router.post("/library/{name}/send")
def send_program(
    request: Request,
    name: str,
    page: Writing,
    machines: Annotated[list[str] | None, Form()] = None,
    version: NumberField = None,
    override: Override = None,
    reason: Reason = "",
) -> HTMLResponse:
    """Queue the program for the picked machines (operators); a program check's errors need
    the override box and a reason (programmers)."""
    if not machines:
        actions.policy.may_queue(page.who, JobKind.SEND)  # the role first, as the API does
        raise InputError("pick at least one machine")
    order = JobRequest(
        kind=JobKind.SEND,
        program=name,
        version=version,
        machines=machines,
        override=_override(override, reason),
    )
    # each machine that takes it gets it; each refusal is named in the panel, not at the top
    try:
        done = actions.queue.queue_each(_svc(request), page.who, order)
    except actions.queue.RefusedEverywhere as nowhere:
        answer = _html("_sent.html", page, request, queued=[], refused=nowhere.refused)
        answer.status_code = 409
        return answer
    queued = [j.model_dump(mode="json") for j in done.jobs]
    return _html("_sent.html", page, request, queued=queued, refused=done.refused)


@router.post("/library")
async def upload_program(
    request: Request,
    page: Writing,
    file: UploadFile,
    name: ProgramField = "",
    comment: Annotated[str, Form(max_length=1000)] = "",
) -> Response:
    """Store an uploaded file as a new draft version (programmers)."""
    actions.library.may_upload(page.who)  # before the file is read
    data = await _read_upload(file)
    program = name.strip() or (file.filename or "")
    version = await run_in_threadpool(
        lambda: actions.library.upload_program(
            _svc(request), page.who, program, data, comment=comment
        )
    )
    return _redirect(request, f"/library/{quote(program)}?v={version.number}")


def _redirect(request: Request, target: str) -> Response:
    if _is_htmx(request):
        return Response(status_code=204, headers={"HX-Location": target})
    return RedirectResponse(target, status_code=303)


# -- inbox --------------------------------------------------------------------------------


@router.get("/inbox")
def inbox_page(request: Request, page: Viewing, state: str = "new") -> HTMLResponse:
    """Programs received from the machines."""
    try:
        states = [ReceivedState(state)] if state != "all" else list(ReceivedState)
    except ValueError:
        raise InputError(f"state {state[:20]!r}: new, accepted, discarded, failed or all") from None
    found = actions.inbox.list_received(_svc(request), page.who, states)
    items = [r.model_dump(mode="json") for r in found]
    template = "_inbox.html" if _is_htmx(request) else "inbox.html"
    return _html(template, page, request, items=items, state=state)


@router.get("/inbox/{received_id}")
def received_page(request: Request, received_id: ReceivedId, page: Viewing) -> HTMLResponse:
    """One reception beside the library version of the same program."""
    svc = _svc(request)
    item = actions.inbox.get_received(svc, page.who, received_id)
    new = actions.inbox.received_content(svc, page.who, received_id).data
    old = actions.inbox.base_content(svc, page.who, received_id)
    return _html(
        "received.html",
        page,
        request,
        item=item.model_dump(mode="json", exclude={"base", "diff"}),
        base=item.base.model_dump(mode="json") if item.base is not None else None,
        diff=render.side_by_side(render.program_text(old), render.program_text(new)),
        unified=item.diff,
    )


@router.post("/inbox/{received_id}/accept")
def accept_received(
    request: Request,
    received_id: ReceivedId,
    page: Writing,
    name: ProgramField = "",
) -> Response:
    """Make the reception a new draft version (programmers)."""
    version = actions.inbox.accept_received(
        _svc(request), page.who, received_id, name.strip() or None
    )
    return _redirect(request, f"/library/{quote(version.program)}?v={version.number}")


@router.post("/inbox/{received_id}/discard")
def discard_received(request: Request, received_id: ReceivedId, page: Writing) -> Response:
    """Drop the reception from the inbox (programmers)."""
    actions.inbox.discard_received(_svc(request), page.who, received_id)
    return _redirect(request, "/inbox")


# -- net share ----------------------------------------------------------------------------


@router.get("/netshare")
def netshare_page(request: Request, page: Viewing) -> HTMLResponse:
    """The hybrid net share: its folders and files beside the library, and what it did."""
    found = actions.netshare.net_share(_svc(request), page.who)
    template = "_netshare.html" if _is_htmx(request) else "netshare.html"
    return _html(template, page, request, share=found.model_dump(mode="json"))


# -- history ------------------------------------------------------------------------------


@dataclass(frozen=True)
class _AuditFilters:
    """The history's filters as the person typed them (the form shows them again)."""

    machine: str
    action: str
    actor: str
    program: str

    def as_dict(self) -> dict[str, str]:
        return {
            "machine": self.machine,
            "action": self.action,
            "actor": self.actor,
            "program": self.program,
        }

    def rows(
        self, request: Request, page: Page, limit: int, before: int | None = None
    ) -> list[AuditOut]:
        """The audit rows they select, newest first (a blank filter selects everything)."""
        blank = {k: v.strip() or None for k, v in self.as_dict().items()}
        return actions.admin.list_audit(
            _svc(request),
            page.who,
            machine=blank["machine"],
            action=blank["action"],
            actor=blank["actor"],
            program=blank["program"],
            limit=limit,
            before=before,
        )


def _audit_filters(
    machine: Short = "",
    action: Short = "",
    actor: Short = "",
    program: Annotated[str, Query(max_length=255)] = "",
) -> _AuditFilters:
    return _AuditFilters(machine, action, actor, program)


AuditFilters = Annotated[_AuditFilters, Depends(_audit_filters)]


@router.get("/history")
def history_page(
    request: Request,
    page: Viewing,
    filters: AuditFilters,
    before: Annotated[int | None, Query(ge=1, le=MAX_ID)] = None,
) -> HTMLResponse:
    """The audit trail, filterable, newest first."""
    rows = [r.model_dump(mode="json") for r in filters.rows(request, page, 100, before)]
    typed = filters.as_dict()
    query = "&".join(f"{k}={quote(v)}" for k, v in typed.items() if v.strip())
    machines = sorted(_supervisor(request).machines)
    return _html(
        "history.html", page, request, rows=rows, filters=typed, query=query, machines=machines
    )


@router.get("/history.csv")
def history_csv(request: Request, page: Viewing, filters: AuditFilters) -> Response:
    """The filtered audit trail as CSV (the API's export, for a logged-in person)."""
    return actions.admin.audit_csv_response(filters.rows(request, page, 10_000))


# -- stylesheet of the highlighted code -----------------------------------------------------


@router.get("/static/pygments.css")
def pygments_css() -> Response:
    """Colours of the highlighted G-code."""
    return Response(
        render.pygments_css(),
        media_type="text/css",
        headers={"Cache-Control": "public, max-age=3600"},
    )
