"""The library folder: a full rescan at start, then watched for changes.

Programmers save programs into the library folder (often a network share); every new or
changed file becomes a new draft version, named by its file name. Files are never removed from
the library when they disappear from the folder: versions are history.

A file is taken only once it has stopped changing (same size and modification time on two looks
``settle`` seconds apart), so a program still being copied in does not become a version of
half a program. Names the library refuses (sub-folders, hidden and temporary files) are skipped
with a log line. Network shares (SMB, NFS) do not deliver change notifications reliably:
``watch = "poll"`` in ``[library]`` makes the watcher look at every file's size and
modification time (to the nanosecond, where the file system keeps it) once a second instead,
and take the files whose pair changed.
"""

from __future__ import annotations

import asyncio
import logging
import os
from collections.abc import Callable
from pathlib import Path

from sqlalchemy.orm import Session, sessionmaker

from opendnc.errors import InputError
from opendnc.server.core.components import RunsTask
from opendnc.server.library import checks as program_checks
from opendnc.server.library import versions as library

__all__ = ["LibraryWatcher"]

log = logging.getLogger(__name__)

# Editors' and copy tools' scratch files: never programs.
_SCRATCH_SUFFIXES = (".tmp", ".part", ".swp", ".bak", "~", ".crdownload")


def _is_candidate(path: Path) -> bool:
    name = path.name
    return not name.startswith((".", "~$")) and not name.lower().endswith(_SCRATCH_SUFFIXES)


class LibraryWatcher(RunsTask):
    """Feeds the library from a folder; :meth:`run` until cancelled (a component)."""

    name = "library-watcher"
    needs: tuple[str, ...] = (
        "database",
        "machines",
    )  # it publishes new versions on the machines' bus

    def __init__(
        self,
        folder: Path,
        sessions: sessionmaker[Session],
        *,
        poll: bool = False,
        settle: float = 0.5,
        poll_interval: float = 1.0,
        on_version: Callable[[str, int], None] | None = None,
    ) -> None:
        self.folder = folder
        self.sessions = sessions
        self.poll = poll
        self.settle = settle
        self.poll_interval = poll_interval
        self._seen: dict[str, tuple[int, int]] = {}
        self.on_version = on_version
        self.ready = asyncio.Event()
        """Set once the start-up rescan is done."""

    async def run(self) -> None:
        """Rescan the whole folder, then take changes as they come."""
        self.folder.mkdir(parents=True, exist_ok=True)
        if self.poll:
            await self._poll()
        else:
            await self._notify()

    async def _poll(self) -> None:
        for path in await asyncio.to_thread(self._changed):  # the start-up rescan
            await self.take(path)
        self.ready.set()
        while True:
            await asyncio.sleep(self.poll_interval)
            for path in await asyncio.to_thread(self._changed):
                await self.take(path)

    def _changed(self) -> list[Path]:
        changed = []
        for path in sorted(self.folder.iterdir()):
            try:
                st = path.stat()
            except OSError:
                continue
            # Remembered at once, skipped names too: a refused name is logged once, not each
            # second; a file still growing is looked at again, and the same bytes twice make
            # no second version.
            if self._seen.get(path.name) != (st.st_size, st.st_mtime_ns):
                self._seen[path.name] = (st.st_size, st.st_mtime_ns)
                changed.append(path)
        return changed

    async def _notify(self) -> None:
        from watchfiles import Change, awatch

        # The watch starts with the first iteration; its first (possibly empty) batch says it
        # is running, and only then comes the rescan, so a file saved meanwhile is not missed.
        changes = awatch(
            self.folder,
            force_polling=self.poll,
            recursive=False,
            poll_delay_ms=500,
            debounce=400,
            rust_timeout=300,
            yield_on_timeout=True,
        )
        async for batch in changes:
            if not self.ready.is_set():
                await self.rescan()
                self.ready.set()
            paths = {Path(p) for change, p in batch if change is not Change.deleted}
            for path in sorted(paths):
                await self.take(path)

    async def rescan(self) -> int:
        """Take every file of the folder; returns how many new versions that made."""
        count = 0
        for path in sorted(self.folder.iterdir()):
            count += await self.take(path)
        return count

    async def take(self, path: Path) -> int:
        """Add ``path`` as a version once it is complete; 1 if that made a new version."""
        if not path.is_file() or not _is_candidate(path):
            return 0
        try:
            library.check_program_name(path.name)
        except InputError as exc:
            log.warning("library folder: skipping %s: %s", path.name, exc)
            return 0
        data = await self._settled(path)
        if data is None:
            return 0

        def store() -> tuple[int, bool]:
            with self.sessions.begin() as session:
                version, created = library.add_version(
                    session, path.name, data, author="watcher", source="watcher"
                )
                number, version_id = version.number, version.id
            if created:  # checked on save, after the commit (docs/server.md#program-checks)
                program_checks.check_saved(self.sessions, version_id, path.name, data)
            return number, created

        try:
            number, created = await asyncio.to_thread(store)
        except InputError as exc:
            log.warning("library folder: %s", exc)
            return 0
        if created and self.on_version is not None:
            self.on_version(path.name, number)
        return int(created)

    async def _settled(self, path: Path) -> bytes | None:
        # A file is complete when it looks the same twice, `settle` seconds apart.
        try:
            before = os.stat(path)
            while True:
                await asyncio.sleep(self.settle)
                after = os.stat(path)
                if (after.st_size, after.st_mtime_ns) == (before.st_size, before.st_mtime_ns):
                    break
                before = after
            data = await asyncio.to_thread(path.read_bytes)
        except OSError as exc:  # removed or unreadable meanwhile
            log.warning("library folder: cannot read %s: %s", path.name, exc.strerror or exc)
            return None
        return data if data else None
