"""Auto-receive from a folder on a TNC: a file put on the virtual control over LSV2 reaches
the inbox byte for byte, under its own name; a changed file comes again as a new inbox file, a
kept one is not taken twice after a server restart, and ``after_receive = "delete"`` removes
it from the control once received.

The virtual TNCs run in this process, the server as its own process; files are put on the
controls with opendnc's LSV2 client, as a CAM post or another PC would.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import pytest

from opendnc.lsv2 import Client
from opendnc.server.config.shop import ConfigError, parse_config
from opendnc.server.kinds.base import ReceiveFolder
from opendnc.server.kinds.files import RemoteFile
from opendnc.server.kinds.lsv2 import Lsv2Machine
from opendnc.server.machines.autoreceive import FolderWatch, size_problem
from tests.server.conftest import on
from tests.server.harness import (
    Procs,
    auth,
    create_key,
    free_port,
    httpx,
    start_server,
    wait_for,
)
from tests.server.test_from_the_control import FleetThread

OUT = "TNC:/nc_prog/out"
# Binary-safe: CR LF and LF mixed, a NUL and Latin-1 bytes stay as they are.
PART1 = (
    b"0 BEGIN PGM PART1 MM\r\n1 L X+10 R0 FMAX\n2 ; \xc4\xd6\xdc \x00 end\r\n3 END PGM PART1 MM\r\n"
)
PART2 = b"0 BEGIN PGM PART2 MM\r\n1 TOOL CALL 3 Z S2000\r\n2 END PGM PART2 MM\r\n"
JOB = b"0 BEGIN PGM JOB MM\r\n1 L Z+50 FMAX\r\n2 END PGM JOB MM\r\n"


@pytest.fixture
def tncs(tmp_path: Path) -> Iterator[FleetThread]:
    fleet = FleetThread(tmp_path / "machines", tnc=2, haas=0, serial_haas=0)
    try:
        yield fleet
    finally:
        fleet.stop()


def _put(tncs: FleetThread, machine: str, name: str, data: bytes) -> None:
    m = next(m for m in tncs.fleet.machines if m.name == machine)
    with Client(m.host, m.port, timeout=10.0) as client:
        client.make_dir(OUT)
        client.write_file(f"{OUT}/{name}", data, binary=True)


def _exists(tncs: FleetThread, machine: str, name: str) -> bool:
    m = next(m for m in tncs.fleet.machines if m.name == machine)
    with Client(m.host, m.port, timeout=10.0) as client:
        return client.exists(f"{OUT}/{name}")


def _config(tmp_path: Path, tncs: FleetThread, port: int) -> Path:
    q = json.dumps
    lines = [
        "[server]",
        f"bind = {q(f'127.0.0.1:{port}')}",
        "[library]",
        f"path = {q(str(tmp_path / 'lib' / 'programs'))}",
        f"inbox = {q(str(tmp_path / 'lib' / 'inbox'))}",
        f"archive = {q(str(tmp_path / 'lib' / 'archive'))}",
    ]
    for m in tncs.fleet.machines:
        lines += [
            "[[machines]]",
            f"name = {q(m.name)}",
            'kind = "lsv2"',
            f"host = {q(m.host)}",
            f"port = {m.port}",
            "poll_interval = 0.2",
            f"receive_folder = {q(OUT)}",
            'receive_pattern = "*.h"',
            "receive_every = 1",
        ]
        if m.name == "tnc-2":
            lines.append('after_receive = "delete"')
    path = tmp_path / "shop.toml"
    path.write_text("\n".join(lines) + "\n")
    return path


def _inbox(client: httpx.Client, key: str) -> list[dict[str, Any]]:
    items: list[dict[str, Any]] = client.get(
        "/api/inbox", headers=auth(key), params={"state": ["new", "failed"]}
    ).json()
    return sorted(items, key=lambda i: i["id"])


def _names(items: list[dict[str, Any]]) -> list[tuple[str, str]]:
    return [(i["machine"], i["name"]) for i in items]


@on("sqlite")
def test_files_on_the_tnc_reach_the_inbox_once(
    tmp_path: Path, tncs: FleetThread, procs: Procs, db_url: str
) -> None:
    # Already there when the server starts: received too (the folder is an out-tray).
    _put(tncs, "tnc-1", "NOTES.TXT", b"not a program for the inbox\r\n")
    _put(tncs, "tnc-1", "PART1.H", PART1)
    port = free_port()
    config = _config(tmp_path, tncs, port)
    key = create_key(config, db_url)
    client = start_server(procs, config, db_url)
    with client:
        first = wait_for(
            "PART1.H in the inbox",
            lambda: _inbox(client, key),
            describe=lambda: procs.log("server"),
        )
        assert _names(first) == [("tnc-1", "PART1.H")]
        got = client.get(f"/api/inbox/{first[0]['id']}/content", headers=auth(key)).content
        assert got == PART1
        assert (tmp_path / "lib" / "inbox" / "PART1.H").read_bytes() == PART1

        _put(tncs, "tnc-1", "PART2.H", PART2)
        _put(tncs, "tnc-2", "JOB.H", JOB)
        items = wait_for("PART2.H and JOB.H", lambda: len(_inbox(client, key)) == 3)
        items = _inbox(client, key)
        assert sorted(_names(items)) == [
            ("tnc-1", "PART1.H"),
            ("tnc-1", "PART2.H"),
            ("tnc-2", "JOB.H"),
        ]
        by_name = {i["name"]: i for i in items}
        for name, data in (("PART2.H", PART2), ("JOB.H", JOB)):
            url = f"/api/inbox/{by_name[name]['id']}/content"
            assert client.get(url, headers=auth(key)).content == data
        # after_receive = "delete" on tnc-2 only, and only once the reception is stored.
        wait_for("JOB.H deleted on tnc-2", lambda: not _exists(tncs, "tnc-2", "JOB.H"))
        assert _exists(tncs, "tnc-1", "PART1.H")
        assert _exists(tncs, "tnc-1", "PART2.H")
        deleted = client.get(
            "/api/audit", headers=auth(key), params={"action": "program.receive.delete"}
        ).json()
        assert [(d["machine"], d["result"], d["detail"]["path"]) for d in deleted] == [
            ("tnc-2", "ok", f"{OUT}/JOB.H")
        ]

    procs.stop("server")
    client = start_server(procs, config, db_url)
    with client:
        # A changed file comes again, beside the first one; the kept PART1.H does not. Files
        # of one listing are taken in name order, so once the new PART2.H is in, a second
        # PART1.H would be in too.
        changed = PART2 + b"3 ; CHANGED\r\n"
        _put(tncs, "tnc-1", "PART2.H", changed)
        wait_for(
            "the changed PART2.H",
            lambda: any(i["size"] == len(changed) for i in _inbox(client, key)),
            describe=lambda: (_inbox(client, key), procs.log("server")),
        )
        items = _inbox(client, key)
        assert _names(items)[3:] == [("tnc-1", "PART2.H")]
        assert sorted(_names(items)) == [
            ("tnc-1", "PART1.H"),
            ("tnc-1", "PART2.H"),
            ("tnc-1", "PART2.H"),
            ("tnc-2", "JOB.H"),
        ]
        url = f"/api/inbox/{items[3]['id']}/content"
        assert client.get(url, headers=auth(key)).content == changed
        received = client.get(
            "/api/audit", headers=auth(key), params={"action": "program.receive"}
        ).json()
        assert sorted(r["detail"]["remote"]["path"] for r in received) == [
            f"{OUT}/JOB.H",
            f"{OUT}/PART1.H",
            f"{OUT}/PART2.H",
            f"{OUT}/PART2.H",
        ]
    # Never over the first file: the second PART2.H is written beside it.
    assert (tmp_path / "lib" / "inbox" / "PART2.H").read_bytes() == PART2
    assert (tmp_path / "lib" / "inbox" / "PART2.2.H").read_bytes() == changed


@pytest.mark.parametrize(
    ("entry", "key"),
    [
        ('kind = "haas_serial"\nserial = "/dev/x"\nreceive_folder = "TNC:/x"', "receive_folder"),
        ('kind = "lsv2"\nreceive_folder = "C:/x"', "receive_folder"),
        ('kind = "lsv2"\nreceive_folder = "TNC:/../x"', "receive_folder"),
        ('kind = "lsv2"\nreceive_pattern = "*.h"', "receive_pattern"),
        ('kind = "lsv2"\nreceive_folder = "TNC:/o"\nreceive_pattern = "a/*"', "receive_pattern"),
        ('kind = "lsv2"\nreceive_folder = "TNC:/o"\nreceive_every = 0', "receive_every"),
        ('kind = "lsv2"\nreceive_folder = "TNC:/o"\nafter_receive = "move"', "after_receive"),
    ],
)  # fmt: skip
def test_bad_receive_settings_name_the_key(entry: str, key: str, tmp_path: Path) -> None:
    with pytest.raises(ConfigError) as caught:
        parse_config(f'[[machines]]\nname = "m"\nhost = "h"\n{entry}\n', base=tmp_path)
    assert caught.value.key == f"machines[0].{key}"


def test_receive_settings_are_read(tmp_path: Path) -> None:
    toml = (
        '[[machines]]\nname = "m"\nkind = "lsv2"\nhost = "h"\n'
        'receive_folder = "TNC:\\\\nc_prog\\\\out\\\\"\n'
        'receive_pattern = "*.H"\nafter_receive = "delete"\n'
    )
    machine = parse_config(toml, base=tmp_path).machines[0]
    assert (machine.receive_folder, machine.receive_pattern, machine.after_receive) == (
        "TNC:/nc_prog/out",
        "*.H",
        "delete",
    )
    assert machine.receive_every == 5


def _file(name: str, size: int, second: int) -> RemoteFile:
    when = datetime(2026, 11, 23, 12, 0, second, tzinfo=UTC)
    return RemoteFile(name, f"{OUT}/{name}", size, when, False)


def test_a_file_is_due_once_it_stopped_changing_and_until_received() -> None:
    machine = Lsv2Machine(name="m", host="h", receive_folder=OUT)
    watch = FolderWatch(machine.name, ReceiveFolder(machine.receive_folder, "*.h"))
    a, note = _file("A.H", 10, 1), _file("NOTE.TXT", 5, 1)
    assert watch.due([a, note]) == []  # first sight: it may still be written
    grown = _file("A.H", 20, 2)
    assert watch.due([grown, note]) == []  # it changed between the two listings
    assert watch.due([grown, note]) == [grown]
    watch.mark(grown, b"x" * 20)
    assert watch.due([grown]) == []
    touched = _file("A.H", 20, 3)
    watch.due([touched])
    assert watch.due([touched]) == [touched]
    assert watch.known(touched, b"x" * 20)
    assert not watch.known(touched, b"y" * 20)


def test_a_short_read_is_a_failure_only_if_the_file_did_not_change() -> None:
    listed = _file("A.H", 20, 1)
    assert size_problem(listed, b"x" * 20, listed) is None
    assert size_problem(listed, b"x" * 12, _file("A.H", 12, 2)) == ""
    assert size_problem(listed, b"x" * 12, None) == ""
    reason = size_problem(listed, b"x" * 12, listed)
    assert reason == f"read 12 bytes of {OUT}/A.H, the control lists 20"
