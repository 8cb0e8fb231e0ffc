"""DPRNT listener (fake links, injected clock) and the mounted-folder share push."""

from __future__ import annotations

import csv
import json
import os
import stat
from datetime import UTC, datetime
from pathlib import Path

import pytest

from opendnc.errors import InputError, PeerClosed, TransportError, TransportTimeout
from opendnc.haas import share
from opendnc.haas.listen import CallbackSink, CapturedLine, CsvSink, DprntListener, JsonlSink


class ScriptedStream:
    """Hands out scripted chunks; an exception in the script is raised instead."""

    def __init__(self, script: list[bytes | Exception]) -> None:
        self.script = script
        self.closed = False

    def read(self, max_bytes: int) -> bytes:
        if not self.script:
            raise PeerClosed("end of script")
        item = self.script.pop(0)
        if isinstance(item, Exception):
            raise item
        return item

    def write(self, data: bytes) -> None:
        raise AssertionError("a DPRNT listener never writes")

    def close(self) -> None:
        self.closed = True

    def set_timeout(self, seconds: float | None) -> None:
        pass


def fixed_now() -> datetime:
    return datetime(2026, 1, 2, 3, 4, 5, tzinfo=UTC)


def test_listener_survives_disconnects_and_keeps_tails(tmp_path: Path) -> None:
    links: list[list[bytes | Exception] | Exception] = [
        [b"X  1.5", TransportTimeout("quiet"), b"000 Y -2\r\nPART", PeerClosed("cable")],
        TransportError("connection refused"),
        [b"\r\nZ 3\r\n"],
    ]
    opened: list[ScriptedStream] = []

    def opener(spec: str) -> ScriptedStream:
        item = links.pop(0)
        if isinstance(item, Exception):
            raise item
        opened.append(ScriptedStream(item))
        return opened[-1]

    sleeps: list[float] = []
    got: list[CapturedLine] = []
    csv_path, jsonl_path = tmp_path / "d.csv", tmp_path / "d.jsonl"
    csv_sink, jsonl_sink = CsvSink(csv_path), JsonlSink(jsonl_path)
    listener = DprntListener(
        "tcp://127.0.0.1:1",
        [csv_sink, jsonl_sink, CallbackSink(got.append)],
        opener=opener,  # type: ignore[arg-type]
        now=fixed_now,
        sleep=sleeps.append,
        backoff_start=0.5,
    )
    stats = listener.run(max_lines=4)
    # sinks flush per line: the files are complete before they are closed
    assert len(jsonl_path.read_text().splitlines()) == 4
    csv_sink.close()
    jsonl_sink.close()
    assert [line.text for line in got] == ["X  1.5000 Y -2", "PART", "", "Z 3"]
    # "PART" was cut by the disconnect: kept, but marked so
    assert [line.complete for line in got] == [True, False, True, True]
    assert stats.cut == 1
    assert got[0].numbers == (1.5, -2.0)
    assert stats.connects == 2
    assert stats.errors == 1
    assert sleeps == [0.5, 1.0]  # backoff doubled after the refused connect
    assert all(s.closed for s in opened)
    rows = list(csv.reader(csv_path.read_text().splitlines()))
    assert rows[0] == ["timestamp", "line", "fields", "complete"]
    assert rows[1] == ["2026-01-02T03:04:05+00:00", "X  1.5000 Y -2", "X=1.5 Y=-2", "yes"]
    assert rows[2] == ["2026-01-02T03:04:05+00:00", "PART", "", "no"]
    records = [json.loads(r) for r in jsonl_path.read_text().splitlines()]
    assert records[3] == {
        "timestamp": "2026-01-02T03:04:05+00:00",
        "line": "Z 3",
        "numbers": [3.0],
        "fields": [{"label": "Z", "value": 3.0}],
        "complete": True,
    }
    assert records[1]["complete"] is False


def test_csv_sink_refuses_to_mix_layouts(tmp_path: Path) -> None:
    old = tmp_path / "old.csv"
    old.write_text("timestamp,line,fields\r\n2026-01-02T03:04:05+00:00,A 1,A=1\r\n")
    with pytest.raises(InputError, match="new file"):
        CsvSink(old)
    assert old.read_text().count("\n") == 2  # untouched


def test_listener_max_connects_ends_run() -> None:
    listener = DprntListener(
        "x",
        [],
        opener=lambda spec: ScriptedStream([b"A\n"]),  # type: ignore[arg-type,return-value]
        sleep=lambda s: None,
    )
    assert listener.run(max_connects=2).lines == 2


def test_bad_tcp_source() -> None:
    from opendnc.haas.listen import open_source

    with pytest.raises(InputError):
        open_source("tcp://nohostport")


def test_push_to_mounted_folder(tmp_path: Path) -> None:
    src = tmp_path / "O01234.nc"
    src.write_bytes(b"%\nO01234\nM30\n%\n")
    folder = tmp_path / "share"
    folder.mkdir()
    progress: list[int] = []
    results = share.push([src], share.parse_target(str(folder)), progress=progress.append)
    assert (folder / "O01234.nc").read_bytes() == src.read_bytes()
    assert results[0].size == 15
    assert sum(progress) == 15
    assert [p.name for p in folder.iterdir()] == ["O01234.nc"]  # no temp file left


def test_push_to_mounted_folder_keeps_usual_permissions(tmp_path: Path) -> None:
    # the pushed program must be readable like any file the user creates, not 0600
    src = tmp_path / "O01234.nc"
    src.write_bytes(b"%\nO01234\nM30\n%\n")
    folder = tmp_path / "share"
    folder.mkdir()
    old = os.umask(0o022)
    try:
        share.push([src], share.parse_target(str(folder)))
    finally:
        os.umask(old)
    assert stat.S_IMODE((folder / "O01234.nc").stat().st_mode) == 0o644


def test_push_errors(tmp_path: Path) -> None:
    with pytest.raises(InputError):
        share.parse_target(str(tmp_path / "missing"))
    with pytest.raises(InputError):
        share.push([tmp_path / "nope.nc"], share.parse_target(str(tmp_path)))
    with pytest.raises(InputError):
        share.parse_target("smb://host")


def test_parse_smb_target() -> None:
    target = share.parse_target("smb://op:p%40ss@cnc1:1445/UserData/progs/new")
    assert (target.host, target.port, target.share, target.folder) == (
        "cnc1",
        1445,
        "UserData",
        "progs/new",
    )
    assert (target.username, target.password) == ("op", "p@ss")
    assert target.unc("O1.nc") == r"\\cnc1\UserData\progs\new\O1.nc"


def test_stop_cuts_backoff_short() -> None:
    import threading
    import time

    tried = threading.Event()

    def refuse(spec: str) -> ScriptedStream:
        tried.set()
        raise TransportError("refused")

    listener = DprntListener("x", [], opener=refuse, backoff_start=30.0)  # type: ignore[arg-type]
    thread = threading.Thread(target=listener.run, daemon=True)
    thread.start()
    assert tried.wait(5), "the listener never tried to connect"
    started = time.monotonic()
    listener.stop()
    thread.join(5)
    assert not thread.is_alive()
    assert time.monotonic() - started < 2
