"""The library folder watcher: rescan at start, new and changed files, half-copied files."""

from __future__ import annotations

import asyncio
import time
from pathlib import Path

import pytest
from sqlalchemy.orm import Session, sessionmaker

from opendnc.server.core.errors import NotFound
from opendnc.server.library import versions as library
from opendnc.server.library.watcher import LibraryWatcher


def _versions(sessions: sessionmaker[Session], name: str) -> list[bytes]:
    with sessions() as s:
        try:
            program = library.get_program(s, name)
        except NotFound:
            return []
        return [library.content(s, v) for v in program.versions]


async def _until(check, timeout: float = 20.0) -> None:  # type: ignore[no-untyped-def]
    deadline = time.monotonic() + timeout
    while not check():
        if time.monotonic() > deadline:
            raise AssertionError("timed out")
        await asyncio.sleep(0.05)


@pytest.mark.parametrize("poll", [False, True], ids=["notify", "poll"])
def test_rescan_then_changes_become_versions(
    sessions: sessionmaker[Session], tmp_path: Path, poll: bool
) -> None:
    folder = tmp_path / "programs"
    folder.mkdir()
    (folder / "O01000.nc").write_bytes(b"%\nO01000\nM30\n%\n")
    (folder / ".hidden.nc").write_bytes(b"x")
    (folder / "draft.nc.tmp").write_bytes(b"x")
    (folder / "sub").mkdir()
    (folder / "sub" / "O03000.nc").write_bytes(b"x")

    async def scenario() -> None:
        watcher = LibraryWatcher(folder, sessions, poll=poll, settle=0.2)
        task = asyncio.create_task(watcher.run())
        try:
            await asyncio.wait_for(watcher.ready.wait(), 20)
            assert _versions(sessions, "O01000.nc") == [b"%\nO01000\nM30\n%\n"]
            (folder / "O02000.nc").write_bytes(b"%\nO02000\nM30\n%\n")
            (folder / "O01000.nc").write_bytes(b"%\nO01000\nG00 X1.\nM30\n%\n")
            await _until(lambda: len(_versions(sessions, "O01000.nc")) == 2)
            await _until(lambda: _versions(sessions, "O02000.nc") == [b"%\nO02000\nM30\n%\n"])
            (folder / "O01000.nc").unlink()  # a deleted file keeps its history
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)

    asyncio.run(scenario())
    with sessions() as s:
        names = [p.name for p in library.list_programs(s)]
    assert names == ["O01000.nc", "O02000.nc"]


def test_a_file_still_being_copied_becomes_one_whole_version(
    sessions: sessionmaker[Session], tmp_path: Path
) -> None:
    folder = tmp_path / "programs"
    folder.mkdir()
    whole = b"%\nO04000\n" + b"G01 X1. Y1. F10.\n" * 200 + b"M30\n%\n"

    async def scenario() -> None:
        watcher = LibraryWatcher(folder, sessions, settle=0.4)
        task = asyncio.create_task(watcher.run())
        try:
            await asyncio.wait_for(watcher.ready.wait(), 20)
            with (folder / "O04000.nc").open("wb") as out:
                for start in range(0, len(whole), 512):  # a slow copy: a chunk every 0.1 s
                    out.write(whole[start : start + 512])
                    out.flush()
                    await asyncio.sleep(0.1)
            await _until(lambda: bool(_versions(sessions, "O04000.nc")))
            await asyncio.sleep(1.0)  # time for any late second version to show
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)

    asyncio.run(scenario())
    assert _versions(sessions, "O04000.nc") == [whole]
