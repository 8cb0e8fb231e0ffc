"""The actions layer: every command a person or a program gives the server, in one place.

Each action is a function that takes the :class:`~opendnc.server.actions.base.Services`
(database sessions, the machines' runner), the caller (a
:class:`~opendnc.server.access.auth.Principal`: name and role, from an API key or a web session
alike) and typed arguments; it returns a typed result (:mod:`.models`) or raises a typed
error under :class:`~opendnc.errors.DncError` (``Forbidden`` 403, ``NotFound`` 404,
``Conflict`` 409, ``InputError`` 400, ``Unavailable`` 503). The roles, a machine's
``released_only`` policy, the drip-feed opt-in and the draft rules are decided here and
nowhere else (:mod:`.policy`); the JSON API (:mod:`opendnc.server.http.api`) and the dashboard's
pages (:mod:`opendnc.server.web.pages`) only parse a request, call an action and render its
result, so both give the same answer to the same request.

Modules by subject: :mod:`.library` (programs and versions), :mod:`.queue` (jobs),
:mod:`.checks` (program checks), :mod:`.files` (a control's files), :mod:`.inbox`
(receptions), :mod:`.admin` (keys, the audit trail), :mod:`.machines` (live state, what the
cards tell of the jobs), :mod:`.preview` (a version's dry run and toolpath), :mod:`.netshare`
(the hybrid net share's folders and files), :mod:`.floor` (standard times, parts reported,
downtime reasons), :mod:`.dprnt` (the lines a machine printed),
:mod:`.utilization` (the report and the utilization page's figures), :mod:`.sessions` (a
person's login, session and logout). Reads go through actions as writes do: the pages and
the routes hold no query of their own.

It may import every package under it (core to utilization); the routes (``http/``), the pages
(``web/``) and the machine tasks (``fleet/``) stand above it and call it.
"""

from __future__ import annotations

from opendnc.server.actions import (
    admin,
    checks,
    dprnt,
    files,
    floor,
    inbox,
    library,
    machines,
    netshare,
    policy,
    preview,
    queue,
    sessions,
    utilization,
)
from opendnc.server.actions.base import Caller, Services, require

__all__ = [
    "Caller",
    "Services",
    "admin",
    "checks",
    "dprnt",
    "files",
    "floor",
    "inbox",
    "library",
    "machines",
    "netshare",
    "policy",
    "preview",
    "queue",
    "require",
    "sessions",
    "utilization",
]
