"""The ``files`` capability (docs/files.md) against real peers over loopback: pyftpdlib as the
control's FTP server, and ftplib as a Data Server board that is the FTP client of ours.

The machine in the server tests is a status-only kind defined here (like the MTConnect and
OPC UA kinds, it takes no programs by itself): its ``[machines.files]`` table alone lets it take
them, through the same job path and policy as every other send.
"""

from __future__ import annotations

import ftplib
import hashlib
import io
import os
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, ClassVar

import pytest

from tests.peers import require_module

httpx = require_module("httpx")
require_module("pyftpdlib")
require_module("uvicorn")

from sqlalchemy import select  # noqa: E402

from opendnc.errors import ControlRefused, TransferError  # noqa: E402
from opendnc.ftpserve import Account, FtpFolders, ftp_handler  # noqa: E402
from opendnc.server.access import auth  # noqa: E402
from opendnc.server.app import build  # noqa: E402
from opendnc.server.config.shop import ConfigError, parse_config  # noqa: E402
from opendnc.server.core.status import MachineStatus  # noqa: E402
from opendnc.server.kinds.base import (  # noqa: E402
    Capabilities,
    ConnectorHooks,
    KindSpec,
    MachineBase,
    schema_keys,
)
from opendnc.server.kinds.connector import StatusOnly  # noqa: E402
from opendnc.server.kinds.filedrop import FilesConnector  # noqa: E402
from opendnc.server.kinds.filedrop_config import FilesConfig  # noqa: E402
from opendnc.server.kinds.filedrop_folder import FolderDrop  # noqa: E402
from opendnc.server.kinds.filedrop_ftp import FtpDrop  # noqa: E402
from opendnc.server.kinds.registry import (  # noqa: E402
    KINDS,
    capabilities_of,
    connector_for,
    receive_folder_of,
    register,
)
from opendnc.server.library import versions as library  # noqa: E402
from opendnc.server.netshare.ftpserver import FtpServer, accounts_for  # noqa: E402
from opendnc.server.store.models import AuditEntry, Role  # noqa: E402
from opendnc.sim.ftp import VirtualFtpFolder  # noqa: E402
from tests.server.harness import auth as bearer  # noqa: E402
from tests.server.harness import wait_for, wait_jobs  # noqa: E402
from tests.server.serving import serving  # noqa: E402

PROGRAM = b"%\nO01000 (FILES)\nG00 G90 X0. Y0.\nM30\n%\n"
OTHER = b"%\nO02000 (FROM THE CONTROL)\nG00 G90 X1. Y1.\nM30\n%\n"


# -- a status-only kind of the test's own ---------------------------------------------------
@dataclass(frozen=True, kw_only=True)
class QuietMachine(MachineBase):
    """A machine whose own link reports status only."""

    kind: ClassVar[str] = "quiet"


class QuietConnector(StatusOnly):
    through = "its status link"

    def __init__(self, config: QuietMachine) -> None:
        self.config = config

    async def connect(self) -> None:
        return None

    async def close(self) -> None:
        return None

    async def status(self) -> MachineStatus:
        return MachineStatus(at=datetime.now(UTC), available=True, execution="READY")


def _quiet(config: QuietMachine, hooks: ConnectorHooks) -> QuietConnector:
    return QuietConnector(config)


SPEC = KindSpec(
    kind="quiet",
    label="Status only · test kind",
    schema=QuietMachine,
    keys=schema_keys(QuietMachine),
    parse=lambda raw, prefix, common: QuietMachine(**common),
    connector=_quiet,
    capabilities=lambda config: Capabilities(status_fields=frozenset({"execution"})),
)


@pytest.fixture
def quiet_kind() -> Iterator[None]:
    register(SPEC)
    try:
        yield
    finally:
        KINDS.pop(SPEC.kind, None)


# -- FTP peers with the quirks a test needs ----------------------------------------------------
FTPHandler = ftp_handler()


class Recording(FTPHandler):  # type: ignore[misc]
    """Keeps every command the client sent (class-wide: one test at a time uses it)."""

    commands: ClassVar[list[str]] = []

    def pre_process_command(self, line: str, cmd: str, arg: str) -> None:
        type(self).commands.append(f"{cmd} {arg}".strip())
        super().pre_process_command(line, cmd, arg)


class Flips(FTPHandler):  # type: ignore[misc]
    """A control that keeps a stored file with one byte changed (same size)."""

    def on_file_received(self, file: str) -> None:
        data = bytearray(Path(file).read_bytes())
        data[len(data) // 2] ^= 0x01
        Path(file).write_bytes(bytes(data))


class Truncates(FTPHandler):  # type: ignore[misc]
    """A control that keeps only part of a stored file."""

    def on_file_received(self, file: str) -> None:
        path = Path(file)
        path.write_bytes(path.read_bytes()[:-5])


class NoOverwriteNoMlsd(FTPHandler):  # type: ignore[misc]
    """A control that refuses to rename onto an existing file, and has no MLSD."""

    def ftp_RNTO(self, path: str) -> None:
        if Path(path).exists():
            self.respond("553 Destination exists.")
            return
        super().ftp_RNTO(path)

    def ftp_MLSD(self, path: str) -> None:
        self.respond("502 Command not implemented.")


def _serve(folder: Path, handler: Any = None) -> FtpFolders:
    return FtpFolders([Account("dnc", "pw", folder)], handler=handler).start()


def _drop(port: int) -> FtpDrop:
    config = FilesConfig(mode="ftp", host="127.0.0.1", port=port, user="dnc", password="pw")
    return FtpDrop(config, "m1")


# -- the FTP folder on the control -------------------------------------------------------------
def test_a_send_is_stored_under_a_temporary_name_checked_and_then_renamed(tmp_path: Path) -> None:
    Recording.commands = []
    server = _serve(tmp_path, Recording)
    try:
        _drop(server.port).put("O01000.nc", PROGRAM)
    finally:
        server.close()
    assert [p.name for p in tmp_path.iterdir()] == ["O01000.nc"]
    assert (tmp_path / "O01000.nc").read_bytes() == PROGRAM
    steps = [c.split(" ", 1) for c in Recording.commands if c.split(" ")[0] in _FILE_COMMANDS]
    temp = steps[0][1]
    assert temp.startswith(".O01000.nc.")
    assert temp.endswith(".part")
    assert steps == [
        ["STOR", temp],
        ["SIZE", temp],
        ["RETR", temp],
        ["RNFR", temp],
        ["RNTO", "O01000.nc"],
    ]
    assert "PASV" in Recording.commands or "EPSV" in Recording.commands  # passive by default


_FILE_COMMANDS = {"STOR", "SIZE", "RETR", "RNFR", "RNTO", "DELE"}


@pytest.mark.parametrize(
    ("handler", "reason"),
    [
        (Flips, "read back differs"),
        (Truncates, f"stored {len(PROGRAM) - 5} bytes of {len(PROGRAM)}"),
    ],
)
def test_a_copy_the_control_did_not_keep_whole_is_a_typed_error_and_leaves_no_file(
    tmp_path: Path, handler: Any, reason: str
) -> None:
    (tmp_path / "O01000.nc").write_bytes(b"the old version")
    server = _serve(tmp_path, handler)
    try:
        with pytest.raises(TransferError, match=reason):
            _drop(server.port).put("O01000.nc", PROGRAM)
    finally:
        server.close()
    # the old file is untouched, and the bad copy is gone
    assert [p.name for p in tmp_path.iterdir()] == ["O01000.nc"]
    assert (tmp_path / "O01000.nc").read_bytes() == b"the old version"


def test_a_control_that_will_not_rename_onto_a_file_nor_list_by_mlsd(tmp_path: Path) -> None:
    (tmp_path / "O01000.nc").write_bytes(b"the old version")
    (tmp_path / "O03000.nc").write_bytes(OTHER)
    server = _serve(tmp_path, NoOverwriteNoMlsd)
    try:
        drop = _drop(server.port)
        drop.put("O01000.nc", PROGRAM)
        listing = {f.name: f.size for f in drop.listing("")}
        with pytest.raises(ControlRefused):
            drop.listing("no-such-folder")
    finally:
        server.close()
    assert (tmp_path / "O01000.nc").read_bytes() == PROGRAM
    assert listing == {"O01000.nc": len(PROGRAM), "O03000.nc": len(OTHER)}


# -- configuration --------------------------------------------------------------------------------
def _shop(tmp_path: Path, machines: str, extra: str = "") -> str:
    return (
        f'[library]\npath = "{tmp_path / "lib"}"\ninbox = "{tmp_path / "inbox"}"\n'
        f'archive = "{tmp_path / "archive"}"\n{extra}\n{machines}'
    )


MTC_WITH_FTP = """
[[machines]]
name = "okuma-1"
kind = "mtconnect"
url = "http://127.0.0.1:5000"
[machines.files]
mode = "ftp"
host = "127.0.0.1"
receive = true
receive_folder = "out"
"""


def test_a_status_only_kind_takes_programs_through_its_files_table(tmp_path: Path) -> None:
    config = parse_config(_shop(tmp_path, MTC_WITH_FTP), base=tmp_path)
    (machine,) = config.machines
    assert machine.files is not None
    assert machine.files.user == "anonymous"
    connector = connector_for(machine)
    assert isinstance(connector, FilesConnector)  # the agent's reader, wrapped
    assert capabilities_of(machine).receive
    folder = receive_folder_of(machine)
    assert folder is not None
    assert folder.folder == "out"


@pytest.mark.parametrize(
    ("files", "key"),
    [
        ('mode = "tftp"', "machines[0].files.mode"),
        ('mode = "ftp"', "machines[0].files.host"),
        ('mode = "ftp-server"\npassword = "x"', "machines[0].files.mode"),  # no [ftp_server]
        ('mode = "ftp"\nhost = "h"\nfolder = "/a/../b"', "machines[0].files.folder"),
    ],
)
def test_a_bad_files_table_names_its_key(tmp_path: Path, files: str, key: str) -> None:
    text = '[[machines]]\nname = "m"\nkind = "mtconnect"\nurl = "http://h:5000"\n'
    text += f"[machines.files]\n{files}\n"
    with pytest.raises(ConfigError) as caught:
        parse_config(_shop(tmp_path, text), base=tmp_path)
    assert caught.value.key == key


def _board(name: str, servers: str = "") -> str:
    return (
        f'[[machines]]\nname = "{name}"\nkind = "mtconnect"\nurl = "http://h:5000"\n{servers}'
        f'[machines.files]\nmode = "ftp-server"\npassword = "pw-{name}"\n'
    )


def test_the_ftp_server_opens_the_accounts_of_the_machines_this_server_serves(
    tmp_path: Path,
) -> None:
    text = _board("f1", 'servers = ["dnc-1"]\n') + _board("f2", 'servers = ["dnc-2"]\n')
    config = parse_config(_shop(tmp_path, text, '[ftp_server]\nroot = "boards"\n'), base=tmp_path)
    assert [a.user for a in accounts_for(config.machines, "dnc-1", clustered=True)] == ["f1"]
    assert [a.folder for a in accounts_for(config.machines, "dnc-2", clustered=True)] == [
        tmp_path / "boards" / "f2"
    ]
    # a lone server opens every account; a cluster refuses a board no one server holds
    alone = parse_config(_shop(tmp_path, _board("f3"), "[ftp_server]\n"), base=tmp_path)
    assert [a.user for a in accounts_for(alone.machines, "opendnc", clustered=False)] == ["f3"]
    with pytest.raises(ConfigError, match="pinned"):
        accounts_for(alone.machines, "opendnc", clustered=True)


# -- through the server ---------------------------------------------------------------------------
def _keys(server: Any, *, release: bool) -> str:
    with server.sessions.begin() as session:
        library.add_version(session, "O01000.nc", PROGRAM, author="test")
        if release:
            library.release(session, "O01000.nc", 1, actor="test")
        auth.create_user(session, "ann", Role.PROGRAMMER)
        key: str = auth.create_key(session, "ann", Role.PROGRAMMER, label="test")[1]
    return key


def _received(server: Any) -> list[AuditEntry]:
    with server.sessions() as session:
        return list(
            session.scalars(select(AuditEntry).where(AuditEntry.action == "program.receive"))
        )


def _send(client: Any, key: str, machine: str) -> Any:
    return client.post(
        "/api/jobs", json={"program": "O01000.nc", "machines": [machine]}, headers=bearer(key)
    )


def test_a_send_through_ftp_the_policy_gate_and_receiving_without_echo(
    tmp_path: Path, quiet_kind: None
) -> None:
    control = tmp_path / "control"
    with VirtualFtpFolder(control, user="dnc", password="pw") as ftp:
        text = (
            '[[machines]]\nname = "q1"\nkind = "quiet"\npoll_interval = 0.05\n'
            "released_only = true\n[machines.files]\n"
            f'mode = "ftp"\nhost = "127.0.0.1"\nport = {ftp.port}\nuser = "dnc"\n'
            'password = "pw"\nreceive = true\nreceive_every = 1\n'
        )
        config = parse_config(_shop(tmp_path, text), base=tmp_path)
        server = build(config, database=f"sqlite:///{tmp_path / 'db.sqlite'}")
        key = _keys(server, release=False)
        with serving(server) as url, httpx.Client(base_url=url, timeout=30) as client:
            # a draft to a released_only machine: refused by the one policy decision
            refused = _send(client, key, "q1")
            assert refused.status_code == 409, refused.text
            assert "released" in refused.text
            assert not (control / "O01000.nc").exists()
            with server.sessions.begin() as session:
                library.release(session, "O01000.nc", 1, actor="test")
            reply = _send(client, key, "q1")
            assert reply.status_code in (200, 201), reply.text
            (job,) = wait_jobs(client, key, [j["id"] for j in reply.json()])
            assert job["state"] == "done", job
            assert (control / "O01000.nc").read_bytes() == PROGRAM
            assert [p.name for p in control.iterdir()] == ["O01000.nc"]
            audit = client.get("/api/audit", params={"action": "job.send"}, headers=bearer(key))
            assert any(row["machine"] == "q1" for row in audit.json()), audit.text
            # the control writes a program of its own: it comes to the inbox; ours does not
            (control / "O02000.nc").write_bytes(OTHER)
            # (the sent file was in every listing before this one was: had it echoed, it
            # would be in the inbox by the time this one is)
            wait_for("the control's program in the inbox", lambda: _received(server))
    rows = _received(server)
    assert [row.sha256 for row in rows] == [hashlib.sha256(OTHER).hexdigest()]
    assert [p.read_bytes() for p in (tmp_path / "inbox").rglob("*") if p.is_file()] == [OTHER]


def test_the_ftp_server_mode_with_ftplib_as_the_data_server_board(
    tmp_path: Path, quiet_kind: None
) -> None:
    text = (
        '[[machines]]\nname = "fanuc-1"\nkind = "quiet"\npoll_interval = 0.05\n'
        '[machines.files]\nmode = "ftp-server"\nuser = "board1"\npassword = "pw"\n'
        "receive = true\nreceive_every = 1\n"
    )
    extra = '[ftp_server]\nbind = "127.0.0.1:0"\nroot = "boards"\n'
    config = parse_config(_shop(tmp_path, text, extra), base=tmp_path)
    server = build(config, database=f"sqlite:///{tmp_path / 'db.sqlite'}")
    key = _keys(server, release=True)
    with serving(server) as url, httpx.Client(base_url=url, timeout=30) as client:
        port = server.core.get(FtpServer).port
        reply = _send(client, key, "fanuc-1")
        assert reply.status_code in (200, 201), reply.text
        board = ftplib.FTP(timeout=10)
        board.connect("127.0.0.1", port)
        board.login("board1", "pw")
        try:
            # the board's LIST-GET: it fetches the program the send put there ...
            wait_for("the program in the board's folder", lambda: "O01000.nc" in board.nlst())
            got = io.BytesIO()
            board.retrbinary("RETR O01000.nc", got.write)
            assert got.getvalue() == PROGRAM
            # ... and its LIST-PUT stores one of its own, which comes to the inbox
            board.storbinary("STOR O02000.nc", io.BytesIO(OTHER))
        finally:
            board.quit()
        wait_for("the board's program in the inbox", lambda: _received(server), timeout=30)
    assert [row.sha256 for row in _received(server)] == [hashlib.sha256(OTHER).hexdigest()]


# -- a share: a local (mounted) folder -------------------------------------------------------------
def test_a_send_to_a_local_share_is_written_hidden_read_back_and_then_renamed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    folder = tmp_path / "share"
    folder.mkdir()
    (folder / "O01000.nc").write_bytes(b"the old version")
    renames: list[tuple[str, bytes, bytes]] = []
    replace = os.replace

    def watched(source: Any, target: Any) -> None:
        # what the folder holds at the moment of the rename: the copy whole under its hidden
        # name, the old program still under the real one (an operator never sees a half copy)
        renames.append(
            (Path(source).name, Path(source).read_bytes(), (folder / "O01000.nc").read_bytes())
        )
        replace(source, target)

    monkeypatch.setattr(os, "replace", watched)  # the one FolderDrop calls
    FolderDrop(str(folder), "m1").put("O01000.nc", PROGRAM)
    ((temp, copy, old),) = renames
    assert temp.startswith(".O01000.nc.")
    assert temp.endswith(".part")
    assert copy == PROGRAM
    assert old == b"the old version"
    assert [p.name for p in folder.iterdir()] == ["O01000.nc"]
    assert (folder / "O01000.nc").read_bytes() == PROGRAM


def test_a_copy_the_share_did_not_keep_is_a_typed_error_and_leaves_the_old_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    folder = tmp_path / "share"
    folder.mkdir()
    (folder / "O01000.nc").write_bytes(b"the old version")

    def keeps_a_changed_byte(fd: int) -> None:
        # a mount that stores something else than was written (the read-back must see it)
        os.pwrite(fd, b"X", 3)

    monkeypatch.setattr(os, "fsync", keeps_a_changed_byte)
    with pytest.raises(TransferError, match="read back"):
        FolderDrop(str(folder), "m1").put("O01000.nc", PROGRAM)
    assert [p.name for p in folder.iterdir()] == ["O01000.nc"]  # no temporary copy left
    assert (folder / "O01000.nc").read_bytes() == b"the old version"


def test_a_send_through_a_local_share_and_receiving_by_watching_it_without_echo(
    tmp_path: Path, quiet_kind: None
) -> None:
    folder = tmp_path / "share"
    folder.mkdir()
    text = (
        '[[machines]]\nname = "q1"\nkind = "quiet"\npoll_interval = 0.05\n[machines.files]\n'
        f'mode = "share"\npath = "{folder}"\nreceive = true\nreceive_every = 1\n'
    )
    config = parse_config(_shop(tmp_path, text), base=tmp_path)
    (machine,) = config.machines
    assert capabilities_of(machine).receive
    server = build(config, database=f"sqlite:///{tmp_path / 'db.sqlite'}")
    key = _keys(server, release=True)
    with serving(server) as url, httpx.Client(base_url=url, timeout=30) as client:
        reply = _send(client, key, "q1")
        assert reply.status_code in (200, 201), reply.text
        (job,) = wait_jobs(client, key, [j["id"] for j in reply.json()])
        assert job["state"] == "done", job
        assert [p.name for p in folder.iterdir()] == ["O01000.nc"]
        assert (folder / "O01000.nc").read_bytes() == PROGRAM
        # the control writes a program of its own: it comes to the inbox; the sent one, in
        # every listing since the send, does not come back
        (folder / "O02000.nc").write_bytes(OTHER)
        wait_for("the control's program in the inbox", lambda: _received(server))
    rows = _received(server)
    assert [(row.program, row.sha256) for row in rows] == [
        ("O02000.nc", hashlib.sha256(OTHER).hexdigest())
    ]
    assert [p.read_bytes() for p in (tmp_path / "inbox").rglob("*") if p.is_file()] == [OTHER]
    # a received file is kept on the share (after_receive = "keep", the default)
    assert sorted(p.name for p in folder.iterdir()) == ["O01000.nc", "O02000.nc"]
