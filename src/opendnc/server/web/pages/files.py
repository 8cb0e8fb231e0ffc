"""The file browser of a control that has one: a folder's listing, a file's download, and the
jobs that change files (put, delete, receive, take back into the library)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Annotated

from fastapi import APIRouter, Form, Request, UploadFile
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import HTMLResponse, Response

from opendnc.server import actions
from opendnc.server.access import auth
from opendnc.server.actions.models import Content, JobKind, JobOut
from opendnc.server.core.errors import Conflict, Unavailable
from opendnc.server.web.pages.base import ControlPath, Page, Viewing, Writing, html, read_upload

__all__ = ["router"]

router = APIRouter(include_in_schema=False)


@router.get("/machines/{name}/files")
async def machine_files_page(
    request: Request, name: str, page: Viewing, path: str | None = None, note: str = ""
) -> HTMLResponse:
    """A folder of the control (a fragment the machine page loads), read on the machine's
    own link."""
    folder = await actions.files.list_folder(page.svc, page.who, name, path)
    return html("_files.html", page, request, note=note, **folder.model_dump(mode="json"))


@router.get("/machines/{name}/files/download")
async def machine_file_download(name: str, path: str, page: Viewing) -> Response:
    """One file of the control, as a download."""
    return _download(await actions.files.read_file(page.svc, page.who, name, path))


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
        return html("_files.html", page, request, note=note, machine=job.machine, entries=[])


def _folder_of(path: str) -> str:
    return path.replace("\\", "/").rsplit("/", 1)[0]


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
    data = await read_upload(file)
    job = await run_in_threadpool(
        actions.files.put_file, page.svc, page.who, name, folder, file.filename or "", data
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
    job = await run_in_threadpool(action, page.svc, page.who, machine, path)
    return await _after_file_job(request, page, job, _folder_of(path))


@router.post("/machines/{name}/files/take-back")
async def machine_file_take_back(
    request: Request, name: str, page: Writing, path: Annotated[str, Form(max_length=255)]
) -> HTMLResponse:
    """Take a file of the control back into the library as a new draft version of the
    program of its name: a ``receive`` job (programmers)."""
    job = await run_in_threadpool(actions.files.take_back, page.svc, page.who, name, path)
    return await _after_file_job(request, page, job, _folder_of(path))
