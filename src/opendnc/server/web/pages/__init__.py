"""The dashboard's pages, one module per page or group of pages, each a thin adapter over the
actions layer.

Reads render a page (or, for htmx, a fragment); writes check the session's CSRF token, call
the action the API route calls (:mod:`opendnc.server.actions`, which checks the role and the
machine's policy), and answer with the fragment to swap in. A refused write answers with its
status (400, 403, 404, 409, 503) and a message that htmx puts in the page's alert area (see
:mod:`opendnc.server.web`). What a role cannot do is not shown to it, and the action refuses
it anyway. Every read goes through an action too: no page holds a query, and no page calls a
module of the JSON API's routes (``tests/server/test_layers.py``).

A page reaches the server's parts through :class:`.base.Parts` (``page.parts``, or the
``Shop`` dependency where no one is logged in yet). Routes are plain functions where they
touch the database (FastAPI runs them in its thread pool, so the machines' event loop never
waits for a query).

Modules: :mod:`.base` (what every page shares), :mod:`.login`, :mod:`.floor` (overview, wall),
:mod:`.cards` and :mod:`.live` (the machines' cards, the live streams), :mod:`.machines` (a
machine's page and its jobs), :mod:`.files` (a control's file browser), :mod:`.library`
(programs, the editor, sending), :mod:`.preview` (a version's toolpath), :mod:`.inbox`
(receptions, the net share), :mod:`.history` (the audit trail), :mod:`.utilization`.
"""

from __future__ import annotations

from fastapi import APIRouter

from opendnc.server.web.pages import (
    files,
    floor,
    floor_panel,
    history,
    inbox,
    library,
    live,
    login,
    machines,
    preview,
    standards,
    utilization,
)

__all__ = ["ROUTERS"]

ROUTERS: tuple[APIRouter, ...] = (
    login.router,
    floor.router,
    floor_panel.router,
    live.router,
    machines.router,
    files.router,
    library.router,
    preview.router,
    inbox.router,
    history.router,
    utilization.router,
    standards.router,
)
"""Every page's routes, in the order they are added to the app."""
