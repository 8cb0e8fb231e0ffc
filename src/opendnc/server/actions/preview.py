"""Preview actions: what a program version does when run (the dry run's facts) and its
toolpath as the compact binary the program page draws (docs/check.md#toolpath-binary).

A dry run of a 100,000-block program takes seconds, and the page asks twice at once (the
facts beside the drawing, the drawing itself), so the result is kept per program name and
content digest: versions never change, the digest alone would do but the name picks the
control (``.H`` is Klartext). The cache lives in this process, is bounded in bytes, and
computes each entry once however many requests wait for it.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass
from typing import Any

from opendnc.nccheck import CheckResult, check_text
from opendnc.nccheck.backplot import build, encode
from opendnc.server.actions.base import Caller, Services
from opendnc.server.actions.library import program_content

__all__ = ["CACHE_BYTES", "Preview", "PreviewCache", "of_result", "preview", "remember"]

CACHE_BYTES = 64 * 1024 * 1024
"""Toolpaths kept in memory (a 100,000-move program's is about 0.3 MB)."""


@dataclass(frozen=True)
class Preview:
    """The dry run of one version as the preview shows it."""

    name: str
    sha256: str
    facts: dict[str, Any]
    """:meth:`~opendnc.nccheck.CheckResult.to_dict` without the moves and the problems: control,
    units, tools, extents, distances, cycle time, stock, blocks, end."""
    toolpath: bytes
    """The decimated toolpath (:func:`opendnc.nccheck.backplot.encode`)."""
    moves: int
    """Moves of the dry run (before decimation)."""
    points: int
    """Points of the decimated toolpath."""

    @property
    def size(self) -> int:
        """About what the entry holds in memory."""
        return len(self.toolpath) + 4096


def compute(name: str, sha256: str, data: bytes) -> Preview:
    """Dry-run ``data`` (the program ``name``) and decimate its moves."""
    # NC programs are 7-bit text; latin-1 never fails and keeps every byte's position
    return of_result(name, sha256, check_text(data.decode("latin-1"), name=name))


def of_result(name: str, sha256: str, result: CheckResult) -> Preview:
    """The preview of a dry run already made (of the text alone, as :func:`compute` runs it)."""
    facts = result.to_dict()
    facts.pop("moves", None)
    facts.pop("problems", None)
    # the drawing's frame: the moves and the stock, so an empty path still shows its blank
    meta = {"units": facts["units"], "stock": facts["stock"], "extents": facts["extents"]}
    backplot = build(
        result.moves, tools=[t.tool for t in result.tools], extents=result.extents, meta=meta
    )
    return Preview(
        name=name,
        sha256=sha256,
        facts=facts,
        toolpath=encode(backplot),
        moves=len(result.moves),
        points=backplot.point_count,
    )


class PreviewCache:
    """Previews by (name, sha256), least recently used dropped beyond ``limit`` bytes; a
    preview being computed is waited for, not computed again."""

    def __init__(self, limit: int = CACHE_BYTES) -> None:
        self.limit = limit
        self._lock = threading.Lock()
        self._done: OrderedDict[tuple[str, str], Preview] = OrderedDict()
        self._running: dict[tuple[str, str], Future[Preview]] = {}
        self._bytes = 0
        self.waited = 0
        """Requests that waited for a preview another request was making."""

    def get(self, key: tuple[str, str], make: Callable[[], Preview]) -> Preview:
        """The preview of ``key``, made by ``make`` when neither kept nor being made."""
        with self._lock:
            found = self._done.get(key)
            if found is not None:
                self._done.move_to_end(key)
                return found
            running = self._running.get(key)
            if running is not None:
                self.waited += 1
            else:
                future: Future[Preview] = Future()
                self._running[key] = future
        if running is not None:
            return running.result()
        try:
            made = make()
        except BaseException as exc:
            with self._lock:
                del self._running[key]
            future.set_exception(exc)
            raise
        with self._lock:
            del self._running[key]
            self._done[key] = made
            self._bytes += made.size
            self._trim()
        future.set_result(made)
        return made

    def put(self, key: tuple[str, str], made: Preview) -> None:
        """Keep ``made`` for ``key`` unless it is kept or being made already."""
        with self._lock:
            if key in self._done or key in self._running:
                return
            self._done[key] = made
            self._bytes += made.size
            self._trim()

    def _trim(self) -> None:
        while self._bytes > self.limit and len(self._done) > 1:
            _, dropped = self._done.popitem(last=False)
            self._bytes -= dropped.size

    def clear(self) -> None:
        """Forget every kept preview."""
        with self._lock:
            self._done.clear()
            self._bytes = 0


CACHE = PreviewCache()
"""The process's previews (content-addressed, so servers in one process may share it)."""


def preview(svc: Services, who: Caller, name: str, number: int | None) -> Preview:
    """The preview of version ``number`` of ``name`` (the newest without it); viewers."""
    content = program_content(svc, who, name, number)
    key = (name, content.sha256)
    return CACHE.get(key, lambda: compute(name, content.sha256, content.data))


def remember(name: str, sha256: str, result: CheckResult) -> None:
    """Keep the preview of a text-alone dry run someone else made (the library's check on
    save), so the page's preview does not run it again."""
    CACHE.put((name, sha256), of_result(name, sha256, result))
