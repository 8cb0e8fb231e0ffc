"""Temp file + rename: a failed receive leaves nothing at the destination."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest

from opendnc.errors import InputError, TransferError
from opendnc.xmodem.files import atomic_output


def test_success_renames_into_place(tmp_path: Path) -> None:
    target = tmp_path / "out.nc"
    with atomic_output(target) as pending:
        pending.handle.write(b"%\nO1\n%\n")
        assert not target.exists()
        assert pending.temp.parent == tmp_path
    assert target.read_bytes() == b"%\nO1\n%\n"
    assert list(tmp_path.iterdir()) == [target]


def test_failure_removes_the_temp_file_and_keeps_the_old_target(tmp_path: Path) -> None:
    target = tmp_path / "out.nc"
    target.write_bytes(b"old")

    def interrupted_receive() -> None:
        with atomic_output(target) as pending:
            pending.handle.write(b"partial")
            raise TransferError("line dropped")

    with pytest.raises(TransferError):
        interrupted_receive()
    assert target.read_bytes() == b"old"
    assert list(tmp_path.iterdir()) == [target]


def test_target_can_be_renamed_before_commit(tmp_path: Path) -> None:
    with atomic_output(tmp_path / "program.nc") as pending:
        pending.handle.write(b"x")
        pending.target = tmp_path / "O05555.nc"
    assert [p.name for p in tmp_path.iterdir()] == ["O05555.nc"]


def test_missing_folder_is_an_input_error(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="does not exist"), atomic_output(tmp_path / "no" / "x"):
        pass


def test_output_gets_umask_permissions(tmp_path: Path) -> None:
    old = os.umask(0o027)
    try:
        with atomic_output(tmp_path / "out.nc") as pending:
            pending.handle.write(b"x")
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "out.nc").stat().st_mode) == 0o640
