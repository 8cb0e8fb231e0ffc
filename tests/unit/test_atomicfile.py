"""The one temp-file-and-rename helper: permissions, cleanup, no partial file under the name."""

from __future__ import annotations

import os
import stat
from collections.abc import Iterator
from pathlib import Path

import pytest

from opendnc.atomicfile import AtomicWriter, atomic_write, create_temp, file_mode


@pytest.fixture
def umask_027() -> Iterator[int]:
    """A umask unlike mkstemp's 0600, so a file still carrying mkstemp's mode is caught."""
    old = os.umask(0o027)
    try:
        yield 0o640
    finally:
        os.umask(old)


def mode_of(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def test_file_mode_follows_the_umask(umask_027: int) -> None:
    assert file_mode() == umask_027
    os.umask(0o002)
    assert file_mode() == 0o664


def test_success_has_umask_mode_and_no_leftovers(tmp_path: Path, umask_027: int) -> None:
    target = tmp_path / "O1000.nc"
    with atomic_write(target) as out:
        out.write(b"%\nO1000\n%\n")
        assert not target.exists(), "partial content visible under the target name"
        (temp,) = tmp_path.iterdir()
        assert temp.name.startswith(".O1000.nc.")
        assert temp.name.endswith(".part")
        assert mode_of(temp) == umask_027
    assert target.read_bytes() == b"%\nO1000\n%\n"
    assert mode_of(target) == umask_027
    assert list(tmp_path.iterdir()) == [target]


@pytest.mark.parametrize("error", [ValueError("bad block"), KeyboardInterrupt()])
def test_any_exception_removes_temp_and_keeps_old_target(
    tmp_path: Path, error: BaseException
) -> None:
    target = tmp_path / "prog.h"
    target.write_bytes(b"old")

    def interrupted() -> None:
        with atomic_write(target, fsync=True) as out:
            out.write(b"half")
            raise error

    with pytest.raises(type(error)):
        interrupted()
    assert target.read_bytes() == b"old"
    assert list(tmp_path.iterdir()) == [target]


def test_writer_keeps_handle_across_calls_and_renames_late(tmp_path: Path) -> None:
    writer = AtomicWriter(tmp_path / "program.nc", buffering=1 << 16)
    for block in (b"a" * 1024, b"b" * 1024):
        writer.write(block)
    writer.target = tmp_path / "O05555.nc"
    writer.commit()
    writer.commit()  # a second commit is a no-op, not an error
    assert [p.name for p in tmp_path.iterdir()] == ["O05555.nc"]
    assert (tmp_path / "O05555.nc").read_bytes() == b"a" * 1024 + b"b" * 1024


def test_discard_leaves_nothing(tmp_path: Path) -> None:
    writer = AtomicWriter(tmp_path / "x.bin")
    writer.write(b"data")
    writer.discard()
    writer.discard()
    assert list(tmp_path.iterdir()) == []


def test_failed_rename_removes_temp(tmp_path: Path) -> None:
    target = tmp_path / "taken"
    target.mkdir()
    (target / "inside").write_bytes(b"")  # os.replace cannot put a file over a non-empty dir
    with pytest.raises(OSError, match="taken"), atomic_write(target) as out:
        out.write(b"x")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["taken"]


def test_missing_folder_raises_oserror(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError):
        AtomicWriter(tmp_path / "no" / "x")


def test_create_temp_is_hidden_and_umask_mode(tmp_path: Path, umask_027: int) -> None:
    fd, path = create_temp(tmp_path)
    os.close(fd)
    assert path.parent == tmp_path
    assert path.name.startswith(".")
    assert path.suffix == ".part"
    assert mode_of(path) == umask_027
