"""The DNC dashboard: pages for people, served by ``opendnc serve`` itself.

Server-rendered Jinja templates with htmx and its server-sent-events extension, both pinned
and shipped in ``static/`` (see ``static/VERSIONS``): no build step, nothing fetched from the
internet. People log in with a password and get a session cookie (:mod:`.session`); the pages
call the same actions (:mod:`opendnc.server.actions`) as the JSON API under ``/api``.

The pages are in :mod:`.pages`, one module per page. It is the top layer under ``app.py``: it
may import every package of the server but the JSON API's modules of routes (``http.api``,
``http.dprnt``, ``http.utilization``, ``http.alerts``), and never ``sqlalchemy`` or the tables
(``store.models``): it reads and writes through the actions. None imports it.
"""

from __future__ import annotations

from pathlib import Path
from urllib.parse import quote

from fastapi import FastAPI, Request
from fastapi.responses import HTMLResponse, JSONResponse, RedirectResponse, Response
from fastapi.staticfiles import StaticFiles

from opendnc.errors import DncError
from opendnc.server.http import edge
from opendnc.server.web import render
from opendnc.server.web.pages import ROUTERS
from opendnc.server.web.pages.base import LoginNeeded

__all__ = ["install"]

STATIC = Path(__file__).parent / "static"


def install(app: FastAPI) -> None:
    """Add the pages, their static files and their error pages to ``app`` (after the API)."""
    for router in ROUTERS:
        app.include_router(router)
    app.mount("/static", StaticFiles(directory=STATIC), name="static")
    app.add_exception_handler(LoginNeeded, _login_needed)  # type: ignore[arg-type]
    app.add_exception_handler(DncError, _error)  # type: ignore[arg-type]
    setattr(app.state, edge.ERROR_PAGE, _error_page)  # what a page gets while the database is away


def _error_page(request: Request, message: str, status: int) -> Response:
    """A page's error answer: an alert fragment for htmx, else the error page."""
    if request.headers.get("HX-Request") == "true":
        html = render.render("_alert.html", message=message, status=status)
        headers = {"HX-Retarget": "#alert", "HX-Reswap": "innerHTML"}
        return HTMLResponse(html, status_code=status, headers=headers)
    html = render.render("error.html", message=message, status=status, page=None, path="")
    return HTMLResponse(html, status_code=status)


async def _login_needed(request: Request, exc: LoginNeeded) -> Response:
    target = f"/login?next={quote(exc.next_url)}"
    if request.headers.get("HX-Request") == "true":
        return Response(status_code=401, headers={"HX-Redirect": target})
    if request.method != "GET":
        return HTMLResponse("log in first", status_code=401)
    return RedirectResponse(target, status_code=303)


async def _error(request: Request, exc: DncError) -> Response:
    """The API answers JSON; a page answers HTML (a fragment for htmx, else a page)."""
    response = await edge.error_response(request, exc)
    if request.url.path.startswith("/api/") or not isinstance(response, JSONResponse):
        return response
    status = response.status_code
    retry = (
        {"Retry-After": response.headers["Retry-After"]}
        if "Retry-After" in response.headers
        else {}
    )
    if request.headers.get("HX-Request") == "true":
        html = render.render("_alert.html", message=str(exc), status=status)
        return HTMLResponse(
            html,
            status_code=status,
            headers={"HX-Retarget": "#alert", "HX-Reswap": "innerHTML", **retry},
        )
    html = render.render(
        "error.html", message=str(exc), status=status, page=None, path=request.url.path
    )
    return HTMLResponse(html, status_code=status, headers=retry)
