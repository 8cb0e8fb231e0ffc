"""The program library: the list, a program's page (versions, text, check, diff), the
editor, and what a person does to a program there (upload, save, release, lock, send)."""

from __future__ import annotations

import gzip
from typing import Annotated, Any
from urllib.parse import quote

from fastapi import APIRouter, Form, Query, Request, UploadFile
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import HTMLResponse, Response

from opendnc.errors import InputError
from opendnc.server import actions
from opendnc.server.actions.models import (
    MAX_ID,
    JobKind,
    JobRequest,
    LiveCheckOut,
    ProgramState,
)
from opendnc.server.core.errors import TooLarge
from opendnc.server.http.downloads import stored_response
from opendnc.server.library.checks import CHECK_BYTES
from opendnc.server.web import listing, render
from opendnc.server.web.pages.base import (
    NumberField,
    ProgramField,
    VersionNumber,
    VersionPath,
    Viewing,
    Writing,
    html,
    is_htmx,
    read_upload,
    redirect,
)

__all__ = ["MAX_EDIT_BYTES", "router"]

router = APIRouter(include_in_schema=False)
MAX_EDIT_BYTES = CHECK_BYTES
"""The editor opens programs up to the size the check reads (16 MiB), so every edited text
can be checked as it is typed; a larger one is edited offline and uploaded."""
# Without scripts the editor's form sends its text as a form field, which the form parser
# caps at 1 MiB; the script sends the text as a file part (up to MAX_EDIT_BYTES).
MAX_EDIT_CHARS = 1024 * 1024
GZIP_FROM = 64 * 1024
"""The editor's text is sent gzipped from this size when the browser takes gzip (NC text
shrinks to about a fifth; level 1 costs ~10 ms a MB)."""
Override = Annotated[str | None, Form(max_length=10)]
Reason = Annotated[str, Form(max_length=1000)]


@router.get("/library")
def library_page(
    request: Request,
    page: Viewing,
    q: Annotated[str, Query(max_length=255)] = "",
    text: Annotated[str, Query(max_length=255)] = "",
) -> HTMLResponse:
    """Programs, searchable by name or title and in their text."""
    found = actions.library.list_programs(page.svc, page.who, q, text)
    programs = [p.model_dump(mode="json") for p in found]
    template = "_programs.html" if is_htmx(request) else "library.html"
    return html(template, page, request, programs=programs, q=q, text=text)


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
    svc, who = page.svc, page.who
    program = actions.library.get_program(svc, who, name)
    shown = actions.library.program_content(svc, who, name, v)
    number = v if v is not None else program.versions[-1].number
    version = next(x for x in program.versions if x.number == number)
    text = render.program_text(shown.data)
    released = [x.number for x in program.versions if x.state is ProgramState.RELEASED]
    check = actions.checks.version_check(svc, who, name, number)
    marks = listing.marks(p.model_dump() for p in check.problems)  # its rows show them
    context: dict[str, Any] = {
        "program": program.model_dump(mode="json"),
        "shown": version.model_dump(mode="json"),
        "released": released[-1] if released else None,
        "listing": listing.window(text, name=name, size=len(shown.data), line=line),
        "check": check.model_dump(mode="json"),
        "marks": marks,
        "marks_data": {n: [m.severity, m.message] for n, m in marks.items()},
        "diff": None,
    }
    if a is not None and b is not None:
        old = actions.library.program_content(svc, who, name, a).data
        new = actions.library.program_content(svc, who, name, b).data
        context["diff"] = render.side_by_side(render.program_text(old), render.program_text(new))
        context["a"], context["b"] = a, b
    machines = [
        {"name": m.name, "released_only": m.released_only, "online": m.online}
        for m in actions.machines.list_machines(svc, who)
    ]
    return html("program.html", page, request, machines=machines, **context)


@router.get("/library/{name}/versions/{number}/download")
def download_version(name: str, number: VersionPath, page: Viewing) -> Response:
    """The bytes of one version, as a file."""
    stored = actions.library.program_stored(page.svc, page.who, name, number)
    response = stored_response(page.svc.reads, stored)  # streamed as the browser reads it
    response.headers["Content-Disposition"] = f'attachment; filename="{stored.name}"'
    return response


def _override(override: str | None, reason: str) -> str | None:
    # the form's "override" box: ticked, its reason (blank is refused by the rules); else none
    return reason if override else None


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
    actions.library.release_version(page.svc, page.who, name, number, _override(override, reason))
    return redirect(request, f"/library/{quote(name)}?v={number}")


@router.get("/library/{name}/checks")
def machine_checks(
    request: Request, name: str, page: Viewing, version: VersionNumber | None = None
) -> HTMLResponse:
    """The send form's list: a version's program check on each machine (a fragment)."""
    names = list(page.parts.machines.machines)
    found = actions.checks.machine_checks(page.svc, page.who, name, version, names)
    rows = [c.model_dump(mode="json") for c in found]
    return html("_machine_checks.html", page, request, checks=rows, program=name)


@router.get("/library/{name}/versions/{number}/edit")
def edit_page(
    request: Request,
    name: str,
    number: VersionPath,
    page: Viewing,
    line: Annotated[int | None, Query(ge=1, le=MAX_ID)] = None,
) -> HTMLResponse:
    """The editor: version ``number`` as text to change and save as a new draft
    (programmers), opened at ``line`` (with its check's message) when given."""
    actions.library.may_upload(page.who)
    program = actions.library.get_program(page.svc, page.who, name)
    version = next((x for x in program.versions if x.number == number), None)
    if version is not None and version.size > MAX_EDIT_BYTES:
        raise InputError(
            f"{name} v{number} is {render.human_size(version.size)}: the browser's editor "
            f"takes {render.human_size(MAX_EDIT_BYTES)}; download it, edit it and upload it"
        )
    # the text itself is fetched by the page's script (``edit_text``): a program of
    # megabytes parsed as HTML and copied into the editor cost seconds
    head = actions.library.program_content(page.svc, page.who, name, number).data[:4096]
    shown = version or program.versions[-1]
    check = actions.checks.version_check(page.svc, page.who, name, number)
    return html(
        "editor.html",
        page,
        request,
        program=program.model_dump(mode="json"),
        shown=shown.model_dump(mode="json"),
        language=render.language_of(name, head),
        check=check.model_dump(mode="json"),
        line=line,
    )


@router.get("/library/{name}/versions/{number}/text")
def edit_text(request: Request, name: str, number: VersionPath, page: Viewing) -> Response:
    """The text the editor opens (programmers): the version's bytes, gzipped when the
    browser takes it (a program of 10 MB is about 2 MB on the wire)."""
    actions.library.may_upload(page.who)
    data = actions.library.program_content(page.svc, page.who, name, number).data
    headers = {"Cache-Control": "private, no-cache", "Vary": "Accept-Encoding"}
    if len(data) >= GZIP_FROM and "gzip" in request.headers.get("accept-encoding", ""):
        data = gzip.compress(data, compresslevel=1, mtime=0)
        headers["Content-Encoding"] = "gzip"
    return Response(data, media_type="text/plain; charset=iso-8859-1", headers=headers)


@router.post("/library/{name}/check")
async def live_check(request: Request, name: str, page: Writing) -> LiveCheckOut:
    """The program check of the text in the request's body, as the editor holds it
    (programmers; nothing stored): the editor's marks as the programmer types. The dry run
    goes in the thread pool, off the event loop."""
    actions.library.may_upload(page.who)  # before the body is read
    data = await _body(request, MAX_EDIT_BYTES)
    return await run_in_threadpool(actions.checks.live_check, page.svc, page.who, name, data)


async def _body(request: Request, limit: int) -> bytes:
    # read the body piece by piece, refusing it once it passes ``limit``
    length = request.headers.get("content-length", "")
    if length.isdigit() and int(length) > limit:
        raise TooLarge(f"the text is larger than the check reads ({render.human_size(limit)})")
    parts: list[bytes] = []
    size = 0
    async for piece in request.stream():
        size += len(piece)
        if size > limit:
            raise TooLarge(f"the text is larger than the check reads ({render.human_size(limit)})")
        parts.append(piece)
    return b"".join(parts)


@router.post("/library/{name}/versions/{number}/edit")
async def save_edit(
    request: Request,
    name: str,
    number: VersionPath,
    page: Writing,
    text: Annotated[str | None, Form(max_length=MAX_EDIT_CHARS)] = None,
    file: UploadFile | None = None,
    comment: Annotated[str, Form(max_length=1000)] = "",
) -> Response:
    """Save the edited text (the ``text`` field, or the script's ``file`` part: UTF-8) as a
    new draft with its comment (programmers); the program page of the new version shows its
    check."""
    actions.library.may_upload(page.who)
    if file is not None:
        try:
            text = (await read_upload(file)).decode("utf-8")
        except UnicodeDecodeError:
            raise InputError("the edited text is not UTF-8") from None
    if text is None:
        raise InputError("no text to save")
    edited = text
    saved = await run_in_threadpool(
        lambda: actions.library.save_edit(page.svc, page.who, name, number, edited, comment=comment)
    )
    return redirect(request, f"/library/{quote(name)}?v={saved.number}#check")


@router.post("/library/{name}/lock")
def lock_program(
    request: Request, name: str, page: Writing, locked: Annotated[bool, Form()]
) -> Response:
    """Lock or unlock a program (approvers)."""
    actions.library.set_locked(page.svc, page.who, name, locked)
    return redirect(request, f"/library/{quote(name)}")


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
        done = actions.queue.queue_each(page.svc, page.who, order)
    except actions.queue.RefusedEverywhere as nowhere:
        answer = html("_sent.html", page, request, queued=[], refused=nowhere.refused)
        answer.status_code = 409
        return answer
    queued = [j.model_dump(mode="json") for j in done.jobs]
    return html("_sent.html", page, request, queued=queued, refused=done.refused)


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
    data = await read_upload(file)
    program = name.strip() or (file.filename or "")
    version = await run_in_threadpool(
        lambda: actions.library.upload_program(page.svc, page.who, program, data, comment=comment)
    )
    return redirect(request, f"/library/{quote(program)}?v={version.number}")


@router.get("/static/pygments.css")
def pygments_css() -> Response:
    """Colours of the highlighted G-code."""
    return Response(
        render.pygments_css(),
        media_type="text/css",
        headers={"Cache-Control": "public, max-age=3600"},
    )
