"""Answers for requests that fail before or outside the routes' own error mapping.

* A request the routes cannot validate is 422 with FastAPI's list of errors, but every input
  echoed back is made printable first: bytes that are not UTF-8 (a binary body sent to a JSON
  route) crashed the default encoder, a non-finite number (``1e400`` reads as infinity) is not
  JSON, and a 60,000-character query does not need to come back whole.
* Non-finite numbers in a JSON body are refused (422) before any model sees them: the API's
  numbers are counts, ids and versions, never infinities.
* A database that cannot be reached is 503 with one line saying so (a page: an HTML page),
  logged once per outage (:mod:`opendnc.server.store.health`), not a traceback per request.
  While an outage is known, :class:`OutageGate` answers so at once, before a route waits for
  a silent database, and lets a request that is already waiting go with the same answer.
* Anything else unexpected is logged with its traceback and answered 500 with a one-line body.
"""

from __future__ import annotations

import asyncio
import json
import logging
import math
from collections.abc import Callable, Coroutine
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse, Response
from sqlalchemy.exc import DataError, DBAPIError, InterfaceError, OperationalError
from sqlalchemy.exc import TimeoutError as PoolTimeout
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from opendnc.errors import DncError
from opendnc.server.core.components import core_of
from opendnc.server.core.errors import TooManyRequests, http_status
from opendnc.server.http import deps
from opendnc.server.http.clients import StreamsFull
from opendnc.server.http.sessions import SessionRoute
from opendnc.server.store.health import is_database_down

# PostgreSQL's SQLSTATE for "numeric value out of range" (psycopg's NumericValueOutOfRange).
# Read from the error, not its class: importing psycopg would cost every server's start, a
# SQLite one's too (on SQLite the same input is an OverflowError).
NUMERIC_OUT_OF_RANGE = "22003"

__all__ = [
    "ECHO_LIMIT",
    "OUTAGE_FREE",
    "ApiRoute",
    "OutageGate",
    "StrictJsonRequest",
    "error_response",
    "install",
    "printable",
    "strict_json",
]

log = logging.getLogger("opendnc.server")


async def error_response(_request: Request, exc: DncError) -> JSONResponse:
    """The JSON answer to ``exc`` (its status, one line, and the headers it calls for)."""
    status = http_status(exc)
    headers: dict[str, str] | None = None
    if status == 401:
        headers = {"WWW-Authenticate": "Bearer"}
    elif isinstance(exc, TooManyRequests | StreamsFull):
        headers = {"Retry-After": str(exc.retry_after)}
    elif status == 500:
        log.error("unexpected error", exc_info=exc)
    return JSONResponse({"detail": str(exc) or type(exc).__name__}, status, headers=headers)


ECHO_LIMIT = 200  # characters of a refused input shown back


def printable(value: Any, depth: int = 0) -> Any:
    """``value`` made safe for a JSON error body (bytes decoded, floats finite, cut short)."""
    if depth > 8:
        return "..."
    if isinstance(value, bytes):
        value = value[: ECHO_LIMIT * 4].decode("utf-8", "replace")
    if isinstance(value, str):
        return value if len(value) <= ECHO_LIMIT else value[:ECHO_LIMIT] + "..."
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    if isinstance(value, bool | int | float) or value is None:
        return value
    if isinstance(value, dict):
        items = list(value.items())[:50]
        return {str(printable(k, depth + 1)): printable(v, depth + 1) for k, v in items}
    if isinstance(value, list | tuple | set | frozenset):
        return [printable(v, depth + 1) for v in list(value)[:50]]
    return printable(str(value), depth + 1)


async def _validation_error(_request: Request, exc: RequestValidationError) -> JSONResponse:
    errors = [printable(dict(error)) for error in exc.errors()]
    return JSONResponse({"detail": errors}, status_code=422)


async def _out_of_range(_request: Request, exc: Exception) -> JSONResponse:
    # A number the database cannot store (an id of 2**63 on SQLite, 2**31 in a PostgreSQL
    # integer column) that reached a query: the client's input, so 422, not 500. Routes
    # bound their numbers themselves; this is the net under them.
    return JSONResponse({"detail": "a number in the request is out of range"}, status_code=422)


async def _data_error(request: Request, exc: DataError) -> JSONResponse:
    if getattr(exc.orig, "sqlstate", None) == NUMERIC_OUT_OF_RANGE:
        return await _out_of_range(request, exc)
    return await _unexpected(request, exc)


DATABASE_RETRY_AFTER = "5"  # seconds a client is asked to wait before it tries again

ErrorPage = Callable[[Request, str, int], Response]
"""How the pages answer an error: (request, message, status) to a response."""
ERROR_PAGE = "error_page"
"""The ``app.state`` attribute the pages put their :data:`ErrorPage` in when they are
installed (the API sits under the pages and does not import them)."""


async def _database_away(request: Request, exc: Exception) -> Response:
    """503 for a database that cannot be reached; anything else from the driver is a bug."""
    if not is_database_down(exc):
        return await _unexpected(request, exc)
    deps.database(request).health.failed(exc)  # logs the first of an outage only
    return database_unavailable(request)


# What anyone is told, with or without a key: the driver's own words name the database's host,
# address and user, so they go to the server log only (once per outage, db_health.py).
DATABASE_UNAVAILABLE = "the database is unavailable now: the server log has the details"


def database_unavailable(request: Request) -> Response:
    """The answer to a request that needs the database while it is away: JSON under
    ``/api/``, else the pages' own error answer (:data:`ERROR_PAGE`: an alert for htmx, an
    HTML page). It never says why (see :data:`DATABASE_UNAVAILABLE`)."""
    message = DATABASE_UNAVAILABLE
    page: ErrorPage | None = getattr(request.app.state, ERROR_PAGE, None)
    if request.url.path.startswith("/api/") or page is None:
        response: Response = JSONResponse({"detail": message}, status_code=503)
    else:
        response = page(request, message, 503)
    response.headers["Retry-After"] = DATABASE_RETRY_AFTER
    return response


# Paths that never need the database: health says what is wrong, the static files are files.
OUTAGE_FREE = ("/api/health", "/static/")


class OutageGate:
    """During a known database outage, answer every request that may need the database 503
    at once (:func:`database_unavailable`), instead of letting each wait for its own deadline
    on a silent connection (5 to 15 s).

    A request already running when the outage is declared and not yet answering is answered
    so too, at that moment: its route goes on in the background (its worker thread is stuck
    until the connection's deadline) and whatever it sends later is dropped. A response that
    has begun (an event stream, a download) is left alone.
    """

    def __init__(self, app: ASGIApp) -> None:
        self.app = app
        self._outage: asyncio.Event | None = None  # set while an outage is known (this loop)
        self._left: set[asyncio.Task[None]] = set()  # answered routes still running

    def _event(self, scope: Scope) -> asyncio.Event:
        if self._outage is None:
            outage = self._outage = asyncio.Event()
            loop = asyncio.get_running_loop()
            health = core_of(scope["app"]).get(deps.Database).health

            def changed(ok: bool) -> None:
                if not loop.is_closed():
                    loop.call_soon_threadsafe(outage.clear if ok else outage.set)

            health.listen(changed)
            if not health.ok:
                outage.set()
        return self._outage

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or scope["path"].startswith(OUTAGE_FREE):
            await self.app(scope, receive, send)
            return
        outage = self._event(scope)
        if outage.is_set():
            await database_unavailable(Request(scope))(scope, receive, send)
            return
        started = answered = False

        async def send_unless_answered(message: Message) -> None:
            nonlocal started
            if answered:
                return  # the client has had its 503
            if message["type"] == "http.response.start":
                started = True
            await send(message)

        route = asyncio.ensure_future(self.app(scope, receive, send_unless_answered))
        declared = asyncio.ensure_future(outage.wait())
        try:
            await asyncio.wait({route, declared}, return_when=asyncio.FIRST_COMPLETED)
        finally:
            declared.cancel()
        if route.done() or started:
            await route
            return
        answered = True
        self._left.add(route)
        route.add_done_callback(self._forget)
        await database_unavailable(Request(scope))(scope, receive, send)

    def _forget(self, route: asyncio.Task[None]) -> None:
        self._left.discard(route)
        if not route.cancelled():
            route.exception()  # the 503 was the answer; the route's own failure is the outage's


async def _unexpected(request: Request, exc: Exception) -> JSONResponse:
    log.error("%s %s failed", request.method, request.url.path, exc_info=exc)
    return JSONResponse(
        {"detail": f"internal error ({type(exc).__name__}); the server log has the details"},
        status_code=500,
    )


class _NotFinite(ValueError):
    pass


def _refuse_constant(name: str) -> float:
    raise _NotFinite(f"{name} is not a number this API takes")


def _finite_float(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise _NotFinite(f"{text[:40]} is out of range")
    return value


def strict_json(data: bytes | str) -> Any:
    """``json.loads`` that refuses ``NaN``, ``Infinity`` and numbers that overflow to them
    (:class:`json.JSONDecodeError`, which FastAPI answers with 422)."""
    try:
        return json.loads(data, parse_constant=_refuse_constant, parse_float=_finite_float)
    except _NotFinite as exc:
        doc = data if isinstance(data, str) else data.decode("utf-8", "replace")
        raise json.JSONDecodeError(str(exc), doc[:ECHO_LIMIT], 0) from None


class StrictJsonRequest(Request):
    """A request whose JSON body may hold only finite numbers."""

    async def json(self) -> Any:
        """The body as JSON (see :func:`strict_json`)."""
        if not hasattr(self, "_json"):
            self._json = strict_json(await self.body())
        return self._json


class ApiRoute(SessionRoute):
    """The JSON API's routes: request sessions (:class:`SessionRoute`) and strict JSON."""

    def get_route_handler(self) -> Callable[[Request], Coroutine[Any, Any, Response]]:
        handler = super().get_route_handler()

        async def strict(request: Request) -> Response:
            return await handler(StrictJsonRequest(request.scope, request.receive))

        return strict


def install(app: FastAPI) -> None:
    """Add the validation and catch-all error answers to ``app``."""
    app.add_exception_handler(RequestValidationError, _validation_error)  # type: ignore[arg-type]
    app.add_exception_handler(OverflowError, _out_of_range)
    app.add_exception_handler(DataError, _data_error)  # type: ignore[arg-type]
    for away in (OperationalError, InterfaceError, PoolTimeout, DBAPIError):
        app.add_exception_handler(away, _database_away)
    app.add_exception_handler(Exception, _unexpected)
    app.add_middleware(OutageGate)
