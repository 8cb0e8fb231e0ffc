"""The program page's preview: the toolpath binary its script draws and the facts beside it.

Both come from one dry run per version (:mod:`opendnc.server.actions.preview`), which a
100,000-block program takes seconds for; the page asks for them after it has loaded, so the
page itself never waits for a dry run.
"""

from __future__ import annotations

from fastapi import APIRouter, Request
from fastapi.responses import HTMLResponse, Response

from opendnc.server import actions
from opendnc.server.actions.preview import Preview
from opendnc.server.web.pages.base import VersionPath, Viewing, html

__all__ = ["router", "toolpath_response"]

router = APIRouter(include_in_schema=False)


def toolpath_response(found: Preview) -> Response:
    """The toolpath as bytes; a version never changes, so the browser may keep it."""
    return Response(
        found.toolpath,
        media_type="application/octet-stream",
        headers={
            "Cache-Control": "private, max-age=86400",
            "ETag": f'"{found.sha256}"',
            "X-Content-SHA256": found.sha256,
            "X-Toolpath-Moves": str(found.moves),
            "X-Toolpath-Points": str(found.points),
        },
    )


@router.get("/library/{name}/versions/{number}/toolpath")
def toolpath(name: str, number: VersionPath, page: Viewing) -> Response:
    """The decimated toolpath of one version (docs/check.md#toolpath-binary)."""
    return toolpath_response(actions.preview.preview(page.svc, page.who, name, number))


@router.get("/library/{name}/versions/{number}/preview")
def facts(request: Request, name: str, number: VersionPath, page: Viewing) -> HTMLResponse:
    """Extents, tools, distances and the estimated time of one version (a fragment)."""
    found = actions.preview.preview(page.svc, page.who, name, number)
    return html(
        "_preview_facts.html",
        page,
        request,
        name=name,
        number=number,
        facts=found.facts,
        moves=found.moves,
        points=found.points,
    )
