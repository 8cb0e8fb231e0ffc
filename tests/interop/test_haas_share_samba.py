"""Net Share push through smbprotocol to a real Samba server started on loopback."""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from typer.testing import CliRunner

from opendnc.cli.main import app
from opendnc.errors import TransportError
from opendnc.haas import share
from tests.peers import missing_peer, require_command, require_module

pytestmark = pytest.mark.interop
PASSWORD = "opendnc-test"

SMB_CONF = """[global]
  workgroup = WORKGROUP
  server role = standalone server
  smb ports = {port}
  interfaces = 127.0.0.1
  bind interfaces only = yes
  pid directory = {d}/run
  lock directory = {d}/lock
  state directory = {d}/state
  cache directory = {d}/cache
  private dir = {d}/private
  ncalrpc dir = {d}/ncalrpc
  log file = {d}/log.%m
  passdb backend = tdbsam:{d}/private/passdb.tdb
  disable netbios = yes
  load printers = no
  printing = bsd
  printcap name = /dev/null
  disable spoolss = yes
  server min protocol = SMB2
[UserData]
  path = {share}
  read only = no
  valid users = {user}
"""


@dataclass
class Samba:
    port: int
    folder: Path
    user: str


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


@pytest.fixture(scope="module")
def samba(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Samba]:
    smbd = require_command("smbd")
    smbpasswd = require_command("smbpasswd")
    require_module("smbclient")
    if os.geteuid() != 0:
        missing_peer("root (smbd needs it to serve a share with a passdb user)")
    base = tmp_path_factory.mktemp("samba")
    for sub in ("run", "lock", "state", "cache", "private", "ncalrpc", "share"):
        (base / sub).mkdir()
    port, user = free_port(), "root"
    conf = base / "smb.conf"
    conf.write_text(SMB_CONF.format(port=port, d=base, share=base / "share", user=user))
    subprocess.run(
        [smbpasswd, "-c", str(conf), "-s", "-a", user],
        input=f"{PASSWORD}\n{PASSWORD}\n",
        text=True,
        check=True,
        capture_output=True,
        timeout=30,
    )
    proc = subprocess.Popen(
        [smbd, "--foreground", "--no-process-group", f"--configfile={conf}", "--debug-stdout"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        # smbd signals its whole process group on shutdown: give it its own session so
        # that cannot reach pytest
        start_new_session=True,
    )
    try:
        deadline = time.monotonic() + 20
        while True:
            try:
                socket.create_connection(("127.0.0.1", port), timeout=1).close()
                break
            except OSError:
                assert proc.poll() is None, "smbd exited; see its log in " + str(base)
                assert time.monotonic() < deadline, "smbd did not start listening"
                time.sleep(0.1)
        yield Samba(port, base / "share", user)
    finally:
        # smbd leads its own process group (see above): stop it and its workers together
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(10)


def test_push_appears_on_share(samba: Samba, tmp_path: Path) -> None:
    (samba.folder / "progs").mkdir(exist_ok=True)
    files = []
    for number, body in ((1234, "T1 M06\nM30"), (1235, "DPRNT[HELLO]\nM30")):
        path = tmp_path / f"O0{number}.nc"
        path.write_bytes(f"%\nO0{number}\n{body}\n%\n".encode())
        files.append(path)
    target = share.parse_target(f"smb://127.0.0.1:{samba.port}/UserData/progs")
    results = share.push(files, target, username=samba.user, password=PASSWORD)
    assert [r.destination for r in results] == [
        f"smb://127.0.0.1:{samba.port}/UserData/progs/{f.name}" for f in files
    ]
    for path in files:
        assert (samba.folder / "progs" / path.name).read_bytes() == path.read_bytes()
    assert sorted(p.name for p in (samba.folder / "progs").iterdir()) == [f.name for f in files]

    # pushing again replaces the file whole
    files[0].write_bytes(b"%\nO01234\nM30\n%\n")
    share.push(files[:1], target, username=samba.user, password=PASSWORD)
    assert (samba.folder / "progs" / files[0].name).read_bytes() == files[0].read_bytes()


def test_cli_push_with_url_credentials(samba: Samba, tmp_path: Path) -> None:
    src = tmp_path / "O00042.nc"
    src.write_bytes(b"%\nO00042\nM30\n%\n")
    url = f"smb://{samba.user}:{PASSWORD}@127.0.0.1:{samba.port}/UserData"
    result = CliRunner().invoke(app, ["haas", "share", "push", str(src), "--to", url])
    assert result.exit_code == 0, result.output
    assert (samba.folder / "O00042.nc").read_bytes() == src.read_bytes()


def test_wrong_password_is_refused(samba: Samba, tmp_path: Path) -> None:
    src = tmp_path / "O00043.nc"
    src.write_bytes(b"%\nO00043\nM30\n%\n")
    target = share.parse_target(f"smb://127.0.0.1:{samba.port}/UserData")
    with pytest.raises(TransportError, match="LOGON_FAILURE"):
        share.push([src], target, username=samba.user, password="wrong")
    assert not (samba.folder / "O00043.nc").exists()
