"""Database sessions for web requests: reads that never lock, writes that lock only briefly.

A request's session follows its HTTP method. ``GET``, ``HEAD`` and ``OPTIONS`` get a *read*
session: on SQLite it starts with a plain ``BEGIN`` (a snapshot under write-ahead logging, which
never takes or waits for the write lock) and a flush in it is refused, so a read route cannot
take the lock by accident. Every other method gets a *write* session, which on SQLite starts
with ``BEGIN IMMEDIATE`` (see :mod:`opendnc.server.store.db`).

The session ends in the worker thread that ran the route, right after the route returns: a
write commits there (a raised error rolls it back), a read ends its snapshot, and the
connection goes back to the pool. It must not wait for FastAPI's dependency exit instead: that
runs after the response is serialised, which needs a worker thread of its own. Under a burst
of requests every worker thread could be waiting for the write lock (or a pool connection) the
finished route still held, while the route waited for a thread: everybody waited for SQLite's
30 s busy timeout and answered 500 (docs/server.md#database-sessions). :class:`SessionRoute`
installs that ending on a router's sync routes; the dependency closes the session (before the
response is sent) in case the route raised or is async.

:func:`read_then_write` serves work that usually only reads but sometimes writes (the key
check that refreshes ``last_used`` now and then): it reads first, and only if the work
changed something runs it again in a short write transaction.
"""

from __future__ import annotations

import functools
import inspect
from collections.abc import AsyncIterator, Callable, Iterator
from contextlib import contextmanager
from typing import Annotated, Any, TypeVar

import anyio
from fastapi import Depends, Request
from fastapi.routing import APIRoute
from sqlalchemy import event
from sqlalchemy.orm import Session

from opendnc.server.http import deps

__all__ = [
    "READ_METHODS",
    "Db",
    "SessionRoute",
    "read_session",
    "read_then_write",
    "request_session",
    "write_session",
]

T = TypeVar("T")

READ_METHODS = frozenset({"GET", "HEAD", "OPTIONS"})
_KIND = "opendnc_request_session"  # Session.info key: "read" or "write"


class ReadOnlyViolation(RuntimeError):
    """A read session was asked to write (a bug in the route, not the client's fault)."""


def _read(request: Request) -> Session:
    """A new read session (a flush in it raises :class:`ReadOnlyViolation`)."""
    session = deps.database(request).reads()
    session.info[_KIND] = "read"
    event.listen(session, "before_flush", _refuse_flush)
    return session


def _write(request: Request) -> Session:
    """A new write session."""
    session = deps.database(request).sessions()
    session.info[_KIND] = "write"
    return session


def _refuse_flush(session: Session, _context: Any, _instances: Any) -> None:
    if session.new or session.dirty or session.deleted:
        raise ReadOnlyViolation("a read request tried to write to the database")


def finish(session: Session) -> None:
    """End ``session``'s transaction and give its connection back (idempotent).

    A write commits; a read commits too, which writes nothing (a flush is refused) and, unlike
    a rollback, keeps the loaded objects readable for the response.
    """
    if session.in_transaction():
        session.commit()


async def request_session(request: Request) -> AsyncIterator[Session]:
    """The request's session (a FastAPI dependency; see the module docstring).

    Made on the event loop (no I/O: the connection is taken at the first query) and closed in a
    thread of its own before the response is sent: a route that raised rolls back.
    """
    session = _read(request) if request.method in READ_METHODS else _write(request)
    try:
        yield session
    except BaseException:
        with anyio.CancelScope(shield=True):
            await anyio.to_thread.run_sync(session.close, limiter=anyio.CapacityLimiter(1))
        raise
    # Normally SessionRoute has ended the transaction in the route's thread; an async route
    # (or one on another router) ends here.
    with anyio.CancelScope(shield=True):
        await anyio.to_thread.run_sync(_finish_and_close, session, limiter=anyio.CapacityLimiter(1))


def _finish_and_close(session: Session) -> None:
    try:
        finish(session)
    finally:
        session.close()


# ``scope="function"``: closed before the response is sent, not after it has streamed.
Db = Annotated[Session, Depends(request_session, scope="function")]


def _ending_sessions(endpoint: Callable[..., Any]) -> Callable[..., Any]:
    if inspect.iscoroutinefunction(endpoint) or inspect.isasyncgenfunction(endpoint):
        return endpoint
    if inspect.isgeneratorfunction(endpoint):
        return endpoint

    @functools.wraps(endpoint)
    def run(*args: Any, **kwargs: Any) -> Any:
        out = endpoint(*args, **kwargs)
        for value in kwargs.values():
            if isinstance(value, Session) and value.info.get(_KIND):
                finish(value)
        return out

    return run


class SessionRoute(APIRoute):
    """A route whose request session (:data:`Db`) ends in the thread that ran it.

    Use as ``APIRouter(route_class=SessionRoute)``; see the module docstring for why.
    """

    def __init__(self, path: str, endpoint: Callable[..., Any], **kwargs: Any) -> None:
        super().__init__(path, _ending_sessions(endpoint), **kwargs)


@contextmanager
def read_session(request: Request) -> Iterator[Session]:
    """A read session for work in the current (worker) thread, ended when the block ends."""
    with _read(request) as session:
        yield session
        finish(session)


@contextmanager
def write_session(request: Request) -> Iterator[Session]:
    """A write transaction for the block: committed at its end, rolled back if it raises."""
    with _write(request) as session, session.begin():
        yield session


def read_then_write(request: Request, work: Callable[[Session], T]) -> T:
    """``work(session)`` in a read session; if it changed anything, again in a write one.

    For work that only now and then writes (run it in a worker thread): the common case takes
    no lock at all, the rare write is one short transaction. ``work`` must be safe to run
    twice (it may only change the database through the session it is given).
    """
    with deps.database(request).reads() as session:
        result = work(session)
        if not (session.new or session.dirty or session.deleted):
            session.commit()  # ends the snapshot; writes nothing
            return result
        session.rollback()
    with write_session(request) as session:
        return work(session)
