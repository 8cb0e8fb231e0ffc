"""What every ``/api`` route module shares: the documented error answers and the caller's
key check, so a module of routes beside :mod:`opendnc.server.http.api` (DPRNT, utilization, alerts)
depends on these and not on the API's own routes.

May import the actions layer, auth and the request helpers; never a module of routes.
"""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import Depends, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from pydantic import BaseModel

from opendnc.server import actions
from opendnc.server.access import auth
from opendnc.server.access.refusals import Refusals
from opendnc.server.access.throttle import Bucket
from opendnc.server.core.components import core_of
from opendnc.server.core.errors import TooManyRequests, Unauthorized
from opendnc.server.http import deps
from opendnc.server.http import sessions as dbsession

__all__ = ["ERRORS", "Caller", "Db", "ErrorOut", "Svc", "Viewer"]


class ErrorOut(BaseModel):
    """Why a request was refused, in one line."""

    detail: str


_REASONS = {
    400: "bad input (the reason says which)",
    401: "no valid API key",
    403: "the key's role does not allow this",
    404: "no such program, version, job, reception, key or machine",
    409: "the current state (or the machine's policy) does not allow this",
    413: "the body is larger than the server takes",
    429: "too many wrong keys with this prefix or from this address; wait Retry-After seconds",
    503: "the machine cannot be reached now",
}
ERRORS: dict[int | str, dict[str, Any]] = {
    status: {"model": ErrorOut, "description": reason} for status, reason in _REASONS.items()
}


# The request's database session, for the API routes that still take one.
Db = dbsession.Db
_bearer = HTTPBearer(auto_error=False, description="an API key: `opendnc keys create`")


async def _principal(
    request: Request,
    credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)],
) -> auth.Principal:
    if credentials is None or credentials.scheme.lower() != "bearer":
        raise Unauthorized("send an API key as 'Authorization: Bearer KEY'")
    svc = _svc(request)
    host = request.client.host if request.client else "?"
    key = credentials.credentials.strip()
    known = svc.keys.get(key)
    if known is not None:
        # checked a moment ago: no worker thread, no query (auth.KeyCache)
        deps.key_use(request).note(known.who.key_id)
        return known.who
    return await run_in_threadpool(_check_key, request, svc, host, key)


def _check_key(request: Request, svc: actions.Services, host: str, key: str) -> auth.Principal:
    # The key is checked before the throttle is asked: a valid key is never refused because
    # of what others sent from its address (docs/server.md#throttling).
    try:
        return auth.authenticate(svc.reads, key, deps.key_use(request), svc.keys).who
    except Unauthorized as exc:
        prefix = key[: auth.KEY_PREFIX_CHARS]
        buckets = [Bucket("key", prefix), Bucket("key-address", host)]
        refusals = core_of(request.app).get(Refusals)
        try:
            svc.guard.check(buckets)
        except TooManyRequests as slowed:
            refusals.note(
                actor="api",
                via="api",
                address=host,
                name=prefix,
                error=str(exc),
                throttled=True,
            )
            raise slowed from None
        svc.guard.failed(buckets)
        refusals.note(actor="api", via="api", address=host, name=prefix, error=str(exc))
        raise


Caller = Annotated[auth.Principal, Depends(_principal)]
Viewer = Caller  # every key is at least a viewer; each action checks the role it needs


def _svc(request: Request) -> actions.Services:
    return core_of(request.app).get(actions.Services)


async def _svc_dep(request: Request) -> actions.Services:
    # async: a plain function dependency costs a trip to a worker thread and back per request
    return _svc(request)


Svc = Annotated[actions.Services, Depends(_svc_dep)]
