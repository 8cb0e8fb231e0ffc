"""Whether the database answers, as this server sees it, and what a request gets when it does not.

The server goes on without its database for a while (machines are polled, a single server's
jobs go on: docs/server.md#health-and-database-outages), but a request that needs it cannot
be answered.
Such a request gets 503 with one line saying why (a page: an HTML page), and the log says so
once per outage, when it begins and when it ends, not with a traceback per request.

An outage begins with the first database error a request, the health probe or
:meth:`DatabaseHealth.failed` reports, and ends with the first statement that goes through
again (an engine event, so any part of the server that reaches the database ends it).

A database that goes *silent* (a network that drops every packet) reports no error: each
request would wait for its own deadline (the connect timeout, the TCP user timeout: 5 to 15 s)
before it failed. So :meth:`DatabaseHealth.watch` asks ``SELECT 1`` every few seconds and
declares an outage when the answer does not come within :data:`WATCH_TIMEOUT`; from then on
requests are answered 503 at once (:class:`opendnc.server.http.edge.OutageGate`), and it keeps
asking, more often, until the database answers again.
"""

from __future__ import annotations

import asyncio
import logging
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

from sqlalchemy import Engine, event, text
from sqlalchemy.exc import DBAPIError, InterfaceError, OperationalError
from sqlalchemy.exc import TimeoutError as PoolTimeout

from opendnc.server.store.db import DatabaseUnreachable, reason_of

__all__ = [
    "PROBE_TIMEOUT",
    "WATCH_INTERVAL",
    "WATCH_TIMEOUT",
    "DatabaseHealth",
    "is_database_down",
    "reason",
]

log = logging.getLogger("opendnc.server")

PROBE_TIMEOUT = 5.0  # seconds the health probe waits for the database's answer (a loaded machine)
# The watch: a SELECT 1 this often while the database answers (cheap: one statement on a pooled
# connection), and this often while it does not (the outage ends as soon as it is noticed).
WATCH_INTERVAL = 2.0
WATCH_INTERVAL_DOWN = 0.5
# Seconds without an answer that make the watch declare an outage. Shorter than the health
# probe's: a false alarm on a very loaded machine ends by itself when the late answer comes
# (any statement that goes through ends an outage), a silent database costs every request
# this long at most.
WATCH_TIMEOUT = 3.0


def is_database_down(exc: BaseException) -> bool:
    """True for the errors that say the database cannot be reached (or is locked) right now,
    as opposed to a bug or a refused change."""
    if isinstance(exc, OperationalError | InterfaceError | PoolTimeout | DatabaseUnreachable):
        return True
    return isinstance(exc, DBAPIError) and bool(exc.connection_invalidated)


def reason(exc: BaseException) -> str:
    """The first line of what the driver said about ``exc``."""
    if isinstance(exc, DBAPIError):
        return reason_of(exc)
    text_ = str(exc).strip()
    return text_.splitlines()[0] if text_ else type(exc).__name__


class DatabaseHealth:
    """The database's state as this server last saw it (thread-safe)."""

    def __init__(self, engine: Engine, *, probe_timeout: float = PROBE_TIMEOUT) -> None:
        self.engine = engine
        self.probe_timeout = probe_timeout
        self.ok = True
        self.reason = ""
        self.since = time.monotonic()  # when the current state began
        self.outages = 0
        self._lock = threading.Lock()
        self._thread = ThreadPoolExecutor(1, thread_name_prefix="db-probe")
        self._probe: asyncio.Future[float] | None = None
        self._probe_started = 0.0
        self._listeners: list[Callable[[bool], None]] = []
        event.listen(engine, "after_cursor_execute", self._statement_went_through)

    def listen(self, listener: Callable[[bool], None]) -> None:
        """Call ``listener(ok)`` at each change of state, in the thread that noticed it (it
        must be quick and thread-safe: ``loop.call_soon_threadsafe`` for the event loop)."""
        self._listeners.append(listener)

    def _tell(self, ok: bool) -> None:
        for listener in list(self._listeners):
            try:
                listener(ok)
            except Exception:  # a listener's bug must not hide the outage from the others
                log.exception("a database health listener failed")

    def close(self) -> None:
        """Stop listening to the engine (the probe's thread ends with the process)."""
        event.remove(self.engine, "after_cursor_execute", self._statement_went_through)
        self._thread.shutdown(wait=False)

    def _statement_went_through(self, *_args: Any) -> None:
        if not self.ok:  # the common case costs one attribute read
            self.answered()

    def answered(self) -> None:
        """The database answered: an outage, if one was going on, is over."""
        with self._lock:
            if self.ok:
                return
            took = time.monotonic() - self.since
            self.ok, self.reason, self.since = True, "", time.monotonic()
        log.warning("the database answers again after %.1f s", took)
        self._tell(True)

    def failed(self, exc: BaseException | str) -> str:
        """The database did not answer (``exc``: the error or a reason); logs the first
        failure of an outage only. Returns the one-line reason."""
        why = exc if isinstance(exc, str) else reason(exc)
        with self._lock:
            if not self.ok:
                return self.reason
            self.ok, self.reason, self.since = False, why, time.monotonic()
            self.outages += 1
        log.warning("the database is unavailable: %s (answering 503 until it is back)", why)
        self._tell(False)
        return why

    def _select_one(self) -> float:
        began = time.monotonic()
        with self.engine.connect() as connection:
            connection.execute(text("SELECT 1"))
            connection.rollback()
        return time.monotonic() - began

    async def probe(self, timeout: float | None = None) -> float | None:
        """Ask the database ``SELECT 1``; the seconds it took, or None when it failed or did
        not answer within ``timeout`` (default ``probe_timeout``). One probe at a time: a
        probe still blocked on a silent connection is waited for again rather than joined by
        another. While an outage is known, the wait is at most a second: the answer is
        already known to be "unavailable" unless the database answers right now."""
        loop = asyncio.get_running_loop()
        if timeout is None:
            timeout = self.probe_timeout if self.ok else min(1.0, self.probe_timeout)
        if self._probe is None or self._probe.done():
            self._probe = asyncio.wrap_future(self._thread.submit(self._select_one), loop=loop)
            self._probe_started = time.monotonic()
        probe = self._probe
        done, _ = await asyncio.wait({probe}, timeout=timeout)
        if not done:
            waited = time.monotonic() - self._probe_started
            self.failed(f"no answer from the database within {waited:.0f} s")
            return None
        exc = probe.exception()
        if exc is not None:
            self.failed(exc)
            return None
        self.answered()
        return probe.result()

    async def watch(
        self,
        interval: float = WATCH_INTERVAL,
        timeout: float = WATCH_TIMEOUT,
        interval_down: float = WATCH_INTERVAL_DOWN,
    ) -> None:
        """Probe the database for ever (a task): every ``interval`` seconds while it answers,
        every ``interval_down`` while it does not; no answer within ``timeout`` is an
        outage (see the module docstring)."""
        while True:
            try:
                await self.probe(timeout)
            except Exception:  # a bug here must not end the watch silently
                log.exception("the database watch's probe failed")
            await asyncio.sleep(interval if self.ok else interval_down)
