"""What every page shares: who is looking (:class:`Page`), the server's parts a page uses
(:class:`Parts`, one typed dependency), the path and form types, and the HTML answer.

A page reaches the server's parts only through :class:`Parts` (``page.parts`` or the
``Shop`` dependency), never by looking a component up itself, and reads and writes only
through the actions (:mod:`opendnc.server.actions`).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING, Annotated, Any

from fastapi import Depends, Form, Path, Query, Request, UploadFile
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import HTMLResponse, RedirectResponse, Response

from opendnc.server import actions
from opendnc.server.access import auth
from opendnc.server.access.key_use import KeyUse
from opendnc.server.access.refusals import Refusals
from opendnc.server.actions.models import MAX_ID, Role
from opendnc.server.core.components import Core, core_of
from opendnc.server.core.errors import TooLarge, Unauthorized
from opendnc.server.core.shifts import Calendar
from opendnc.server.library.versions import MAX_PROGRAM_BYTES
from opendnc.server.machines.dprnt_capture import DprntCapture
from opendnc.server.machines.state import Machines
from opendnc.server.web import render
from opendnc.server.web import session as web_session

if TYPE_CHECKING:
    from opendnc.server.machines.timeline import Timeline

__all__ = [
    "ROLES",
    "ControlPath",
    "JobId",
    "LoginNeeded",
    "NumberField",
    "Page",
    "Parts",
    "ProgramField",
    "ReceivedId",
    "Shop",
    "Short",
    "VersionNumber",
    "VersionPath",
    "Viewing",
    "Writing",
    "html",
    "is_htmx",
    "read_upload",
    "redirect",
]

ROLES = [r.name.lower() for r in Role]


class Parts:
    """The server's parts the pages use, each looked up in the app's core once (then kept:
    the core's components do not change once the server is built)."""

    def __init__(self, core: Core) -> None:
        self._core = core

    @cached_property
    def svc(self) -> actions.Services:
        """The actions' services: every read and write of a page goes through an action."""
        return self._core.get(actions.Services)

    @cached_property
    def machines(self) -> Machines:
        """Every machine's live state, the shop's configuration and the event bus."""
        return self._core.get(Machines)

    @cached_property
    def capture(self) -> DprntCapture:
        """DPRNT capture (each listener's last word)."""
        return self._core.get(DprntCapture)

    @cached_property
    def uses(self) -> KeyUse:
        """Where requests note the keys they used."""
        return self._core.get(KeyUse)

    @cached_property
    def refusals(self) -> Refusals:
        """Refused logins, summed per minute."""
        return self._core.get(Refusals)

    @cached_property
    def timeline(self) -> Timeline:
        """The status timeline."""
        from opendnc.server.outputs.parts import TimelineRecorder

        return self._core.get(TimelineRecorder).timeline

    @property
    def calendar(self) -> Calendar:
        """The shop's calendar and clock ([server] timezone): every time a person reads is
        on it."""
        return self.machines.config.calendar


def parts(request: Request) -> Parts:
    """The app's :class:`Parts` (made at the first page's request)."""
    state = request.app.state
    found = getattr(state, "web_parts", None)
    if not isinstance(found, Parts):
        found = Parts(core_of(request.app))
        state.web_parts = found
    return found


async def _parts(request: Request) -> Parts:
    # async: a plain function dependency costs a trip to a worker thread and back
    return parts(request)


Shop = Annotated[Parts, Depends(_parts)]


class LoginNeeded(Exception):
    """No valid session: pages redirect to the login, htmx requests are told to."""

    def __init__(self, next_url: str) -> None:
        super().__init__(next_url)
        self.next_url = next_url


@dataclass(frozen=True)
class Page:
    """Who is looking, what the page needs to write back safely, and the server's parts."""

    who: auth.Principal
    key: str
    csrf: str
    parts: Parts

    @property
    def svc(self) -> actions.Services:
        """The actions' services (``page.parts.svc``)."""
        return self.parts.svc

    def can(self, role: str) -> bool:
        """True if the user's role includes ``role`` (what the page offers)."""
        return self.who.can(Role.parse(role))


def _page(request: Request) -> Page:
    found = parts(request)
    try:
        who, key = web_session.principal(found.svc, found.uses, request)
    except Unauthorized:
        target = request.url.path + (f"?{request.url.query}" if request.url.query else "")
        raise LoginNeeded(target) from None
    return Page(who, key, web_session.csrf_token(key), found)


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


def html(template: str, page: Page | None, request: Request, **context: Any) -> HTMLResponse:
    """``template`` rendered for ``page`` (None: no one logged in), times on the shop's clock."""
    calendar = parts(request).calendar
    context.setdefault("zone", calendar.zone)
    context.setdefault("zone_name", calendar.zone_name)
    context.setdefault("zone_label", render.zone_label(None, calendar.zone))
    return HTMLResponse(
        render.render(template, page=page, path=request.url.path, roles=ROLES, **context)
    )


def is_htmx(request: Request) -> bool:
    """True for a request htmx made (it swaps a fragment in)."""
    return request.headers.get("HX-Request") == "true"


def redirect(request: Request, target: str) -> Response:
    """Go to ``target`` (htmx: told to, with ``HX-Location``)."""
    if is_htmx(request):
        return Response(status_code=204, headers={"HX-Location": target})
    return RedirectResponse(target, status_code=303)


async def read_upload(file: UploadFile) -> bytes:
    """An uploaded file's bytes; :class:`TooLarge` beyond what the library takes."""
    data = await file.read(MAX_PROGRAM_BYTES + 1)
    if len(data) > MAX_PROGRAM_BYTES:
        raise TooLarge("the upload is larger than the server takes")
    return data
