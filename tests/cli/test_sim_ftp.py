"""`opendnc sim ftp` and `opendnc sim fleet --ftp 1` as subprocesses, with ftplib as the client
(the server's FTP folder peer, docs/files.md#trying-it): they serve, and stop on a signal with
"stopped", status 0 and no traceback."""

from __future__ import annotations

import ftplib
import io
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

from tests.peers import require_module

require_module("pyftpdlib")

CLI = [sys.executable, "-m", "opendnc.cli.main"]
PROGRAM = b"%\nO01000 (OVER FTP)\nG00 G90 X0. Y0.\nM30\n%\n"
STARTED = 30.0  # seconds a simulator may take to listen on a loaded machine
STOPPED = 15.0


def _start(args: list[str], tmp_path: Path) -> tuple[subprocess.Popen[str], Path]:
    ready = tmp_path / "sim.ready"
    proc = subprocess.Popen(
        [*CLI, *args, "--ready-file", str(ready)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=tmp_path,
        env={**os.environ, "COLUMNS": "200"},
    )
    end = time.monotonic() + STARTED
    pause = 0.02
    while not ready.exists():
        if proc.poll() is not None or time.monotonic() > end:
            proc.kill()
            out, err = proc.communicate()
            raise AssertionError(f"{args[:2]} never ready: {out!r} {err!r}")
        time.sleep(pause)
        pause = min(pause * 2, 0.25)
    return proc, ready


def _stop(proc: subprocess.Popen[str], sig: int) -> tuple[str, str]:
    proc.send_signal(sig)
    try:
        out, err = proc.communicate(timeout=STOPPED)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
        raise AssertionError(f"not stopped within {STOPPED} s") from None
    assert proc.returncode == 0, err
    assert "Traceback" not in err, err
    assert out.rstrip().endswith("stopped"), out
    return out, err


def _session(port: int, user: str = "dnc", password: str = "dnc") -> ftplib.FTP:
    client = ftplib.FTP(timeout=10)
    client.connect("127.0.0.1", port)
    client.login(user, password)
    return client  # passive mode: ftplib's default, as the server's FTP client uses


def test_sim_ftp_serves_its_folder_to_ftplib_and_stops_on_sigint(tmp_path: Path) -> None:
    folder = tmp_path / "control"
    args = ["sim", "ftp", str(folder), "--port", "0", "--user", "op", "--password", "pw"]
    proc, ready = _start(args, tmp_path)
    try:
        assert proc.stdout is not None
        banner = proc.stdout.readline()  # printed before the ready file is written
        port = int(re.search(r"ftp://op@127\.0\.0\.1:(\d+)/", banner).group(1))  # type: ignore[union-attr]
        with _session(port, "op", "pw") as client:
            assert "opendnc virtual control" in client.getwelcome()
            client.storbinary("STOR O01000.nc", io.BytesIO(PROGRAM))
            (folder / "O02000.nc").write_bytes(b"%\nO02000\nM30\n%\n")  # the control's own
            assert sorted(client.nlst()) == ["O01000.nc", "O02000.nc"]
            got = io.BytesIO()
            client.retrbinary("RETR O02000.nc", got.write)
            assert got.getvalue() == b"%\nO02000\nM30\n%\n"
            client.rename("O01000.nc", "O01001.nc")
        with _session(port, "op", "pw") as client:  # a second session, after the first quit
            client.voidcmd("TYPE I")  # SIZE counts bytes in binary type only (RFC 3659)
            assert client.size("O01001.nc") == len(PROGRAM)
    except BaseException:
        proc.kill()
        proc.communicate()
        raise
    _stop(proc, signal.SIGINT)
    assert not ready.exists()
    assert (folder / "O01001.nc").read_bytes() == PROGRAM


def test_sim_fleet_ftp_writes_the_files_table_and_serves_it_until_sigterm(tmp_path: Path) -> None:
    require_module("uvicorn")  # its status device is at the fleet's virtual MTConnect agent
    config = tmp_path / "shop.toml"
    args = ["sim", "fleet", "--tnc", "0", "--haas", "0", "--ftp", "1"]
    args += ["--root", str(tmp_path / "fleet"), "--config-out", str(config)]
    proc, ready = _start(args, tmp_path)
    try:
        text = config.read_text()
        # the machine's programs go through its FTP folder: a [machines.files] table
        assert 'name = "ftp-1"' in text
        assert 'kind = "mtconnect"' in text
        assert 'device = "ftp-1"' in text
        table = text[text.index("[machines.files]") :]
        assert 'mode = "ftp"' in table
        port = int(re.search(r"\nport = (\d+)", table).group(1))  # type: ignore[union-attr]
        with _session(port) as client:
            client.storbinary("STOR O01000.nc", io.BytesIO(PROGRAM))
            assert client.nlst() == ["O01000.nc"]
    except BaseException:
        proc.kill()
        proc.communicate()
        raise
    _stop(proc, signal.SIGTERM)
    assert not ready.exists()
    # the folder is the control's program folder under --root
    assert (tmp_path / "fleet" / "ftp-1" / "O01000.nc").read_bytes() == PROGRAM
