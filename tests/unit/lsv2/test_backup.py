"""Backup/sync planning rules (pure: listings in, plans out)."""

from __future__ import annotations

import os
from datetime import UTC, datetime
from pathlib import Path

import pytest

from opendnc.errors import InputError
from opendnc.lsv2.backup import backup, plan_backup, plan_sync, remote_relative
from opendnc.lsv2.ops.files import FileInfo

T0 = datetime(2024, 5, 1, 12, 0, 0, tzinfo=UTC)


def entry(path: str, size: int = 0, *, is_dir: bool = False, when: datetime = T0) -> FileInfo:
    name = path.rstrip("\\").rsplit("\\", 1)[-1]
    return FileInfo(name, path, size, when, is_dir, False, False, False, False, 0)


def test_remote_relative() -> None:
    assert remote_relative("TNC:/nc_prog", "TNC:\\nc_prog\\a\\B.H") == "a/B.H"
    assert remote_relative("TNC:\\", "TNC:\\x.h") == "x.h"
    assert remote_relative("tnc:/NC_PROG/", "TNC:\\nc_prog\\x.h") == "x.h"
    with pytest.raises(InputError):
        remote_relative("TNC:/nc_prog", "TNC:\\other\\x.h")
    with pytest.raises(InputError):
        remote_relative("TNC:/nc_prog", "TNC:\\nc_prog\\..\\x.h")


def test_plan_backup_skips_same_size_and_mtime(tmp_path: Path) -> None:
    listing = [
        entry("TNC:\\p\\sub", is_dir=True),
        entry("TNC:\\p\\sub\\A.H", 3),
        entry("TNC:\\p\\B.H", 4),
        entry("TNC:\\p\\C.H", 5),
        entry("TNC:\\p\\..", is_dir=True),
    ]
    (tmp_path / "B.H").write_bytes(b"bbbb")
    os.utime(tmp_path / "B.H", (T0.timestamp(), T0.timestamp()))
    (tmp_path / "C.H").write_bytes(b"ccccc")  # same size, other mtime: copy again
    copy, current, folders = plan_backup("TNC:/p", listing, tmp_path)
    assert [j.remote for j in copy] == ["TNC:\\p\\sub\\A.H", "TNC:\\p\\C.H"]
    assert copy[0].local == tmp_path / "sub" / "A.H"
    assert [j.remote for j in current] == ["TNC:\\p\\B.H"]
    assert folders == [tmp_path / "sub"]


def test_plan_sync_rules(tmp_path: Path) -> None:
    (tmp_path / "d").mkdir()
    for name, data in [("same.h", b"12"), ("size.h", b"123"), ("newer.h", b"12"), ("new.h", b"")]:
        (tmp_path / name).write_bytes(data)
        os.utime(tmp_path / name, (T0.timestamp(), T0.timestamp()))
    (tmp_path / "d" / "x.h").write_bytes(b"x")
    later = T0.timestamp() + 60
    os.utime(tmp_path / "newer.h", (later, later))
    remote = [
        entry("TNC:\\r\\SAME.H", 2),  # names compare case-insensitively, as on the control
        entry("TNC:\\r\\size.h", 2),
        entry("TNC:\\r\\newer.h", 2),
    ]
    send, current, folders = plan_sync(tmp_path, "TNC:/r", remote)
    assert sorted(j.remote for j in send) == [
        "TNC:\\r\\d\\x.h",
        "TNC:\\r\\new.h",
        "TNC:\\r\\newer.h",
        "TNC:\\r\\size.h",
    ]
    assert [j.remote for j in current] == ["TNC:\\r\\same.h"]
    assert folders == ["TNC:\\r\\d"]


class ShortReadClient:
    """A control whose download delivers fewer bytes than its listing announced."""

    def __init__(self, listed: int, delivered: bytes) -> None:
        self.listed, self.delivered = listed, delivered

    def walk(self, path: str = "TNC:\\", *, multi: bool = True) -> list[FileInfo]:
        return [entry("TNC:\\p\\A.H", self.listed)]

    def file_info(self, path: str) -> FileInfo | None:
        return entry(path, self.listed)

    def make_dir(self, path: str, *, parents: bool = True) -> bool:
        raise AssertionError("not used by backup")

    def download(self, remote: str, local: object, **_: object) -> int:
        Path(str(local)).write_bytes(self.delivered)
        return len(self.delivered)

    def upload(self, local: object, remote: str, **_: object) -> int:
        raise AssertionError("not used by backup")


def test_backup_rejects_a_short_file_and_leaves_nothing(tmp_path: Path) -> None:
    summary = backup(ShortReadClient(10, b"12345"), "TNC:/p", tmp_path)
    assert summary.copied == []
    assert len(summary.failed) == 1
    assert "received 5 bytes, control lists 10" in summary.failed[0].reason
    assert list(tmp_path.iterdir()) == []


def test_backup_sets_remote_mtime(tmp_path: Path) -> None:
    summary = backup(ShortReadClient(5, b"12345"), "TNC:/p", tmp_path)
    assert summary.copied == ["TNC:\\p\\A.H"]
    assert summary.bytes == 5
    assert (tmp_path / "A.H").stat().st_mtime == T0.timestamp()
    assert backup(ShortReadClient(5, b"12345"), "TNC:/p", tmp_path).skipped == ["TNC:\\p\\A.H"]
