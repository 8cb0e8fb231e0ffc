"""``opendnc serve`` starting up: a port in use, a test harness that finds its own server, and
the API waking a machine's task from a worker thread."""

from __future__ import annotations

import signal
import socket
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from opendnc.sim.fleet import server_config
from tests.server.harness import Procs, auth, create_key, start_server, wait_jobs
from tests.server.test_from_the_control import FleetThread

PROGRAM = b"%\r\nO01234 (BRACKET)\r\nG00 X0. Y0.\r\nM30\r\n%\r\n"


@pytest.fixture
def silent_port() -> Iterator[int]:
    """A port on which something accepts connections and never answers (as a virtual Haas's
    MDC port does to an HTTP request: it waits for a Q-command)."""
    with socket.create_server(("127.0.0.1", 0)) as srv:
        yield srv.getsockname()[1]


def _config(tmp_path: Path, bind: str) -> Path:
    config = tmp_path / "shop.toml"
    config.write_text(f'[server]\nbind = "{bind}"\n[library]\npath = "{tmp_path / "lib"}"\n')
    return config


def _serve(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "opendnc.cli.main", "serve", *args],
        capture_output=True,
        text=True,
        timeout=60,
        env={"COLUMNS": "80", "PATH": "/usr/bin:/bin"},  # a narrow terminal must not wrap
        check=False,
    )


@pytest.mark.parametrize("where", ["config", "--bind"])
def test_a_port_in_use_is_one_line_and_nothing_starts(
    tmp_path: Path, silent_port: int, where: str
) -> None:
    address = f"127.0.0.1:{silent_port}"
    config = _config(tmp_path, address if where == "config" else "127.0.0.1:1")
    database = tmp_path / "opendnc.db"
    args = ["--config", str(config), "--db", f"sqlite:///{database}"]
    if where == "--bind":
        args += ["--bind", address]
    done = _serve(*args)
    assert done.returncode == 1, done.stderr
    assert "Traceback" not in done.stderr
    (line,) = done.stderr.strip().splitlines()
    assert line.startswith(f"error: cannot listen on {address}: address already in use")
    assert "--bind" in line
    assert done.stdout == ""
    assert not database.exists()  # stopped before the database (and any machine) was touched


def test_the_demo_on_a_port_in_use_is_one_line(tmp_path: Path, silent_port: int) -> None:
    done = subprocess.run(
        [sys.executable, "-m", "opendnc.cli.main", "demo", "--bind", f"127.0.0.1:{silent_port}"],
        capture_output=True,
        text=True,
        timeout=60,
        env={"COLUMNS": "80", "PATH": "/usr/bin:/bin"},
        check=False,
    )
    assert done.returncode == 1, done.stderr
    (line,) = done.stderr.strip().splitlines()
    assert line.startswith(f"error: cannot listen on 127.0.0.1:{silent_port}: address already")
    assert done.stdout == ""  # no virtual machine was started, no login printed


@pytest.mark.parametrize(
    ("bind", "said"),
    [("8000", "expected HOST:PORT"), ("127.0.0.1:99999", "a port is 0 to 65535")],
)
def test_a_malformed_bind_is_a_usage_error_in_one_line(
    tmp_path: Path, bind: str, said: str
) -> None:
    # the README: every failure is exit status 1, a usage error 2
    done = _serve("--config", str(_config(tmp_path, "127.0.0.1:8000")), "--bind", bind)
    assert done.returncode == 2
    assert done.stderr.strip() == f"error: --bind {bind!r}: {said}"


def test_the_harness_reaches_its_own_server_when_the_configured_port_is_taken(
    tmp_path: Path, procs: Procs, silent_port: int
) -> None:
    # What made test_receive_backup_and_delete_jobs_on_a_tnc hang on its first request: the
    # port picked for the server was taken before the server bound it, the server died, and
    # the harness's "something listens" check handed the test to the silent stranger.
    config = _config(tmp_path, f"127.0.0.1:{silent_port}")
    db_url = f"sqlite:///{tmp_path / 'opendnc.db'}"
    key = create_key(config, db_url, "programmer")
    with start_server(procs, config, db_url) as client:
        assert client.base_url.port != silent_port
        reply = client.put("/api/programs/O01234.nc", content=PROGRAM, headers=auth(key))
        assert reply.status_code == 201, reply.text


def test_a_job_queued_through_the_api_wakes_its_machine_from_the_right_thread(
    tmp_path: Path, procs: Procs, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The API's plain routes run in worker threads; asyncio's debug mode refuses an
    # asyncio.Event set from one (without it, the set does not wake the loop's selector).
    monkeypatch.setenv("PYTHONASYNCIODEBUG", "1")
    fleet = FleetThread(tmp_path / "machines", tnc=1, haas=0)
    try:
        (machine,) = fleet.fleet.machines
        config = tmp_path / "shop.toml"
        config.write_text(
            server_config(fleet.fleet, poll_interval=0.5, library=tmp_path / "lib", check="warn")
        )
        db_url = f"sqlite:///{tmp_path / 'opendnc.db'}"
        key = create_key(config, db_url)
        with start_server(procs, config, db_url) as client:
            client.put("/api/programs/O01234.nc", content=PROGRAM, headers=auth(key))
            queued = client.post(
                "/api/jobs",
                headers=auth(key),
                json={"program": "O01234.nc", "version": 1, "machines": [machine.name]},
            )
            assert queued.status_code == 201, queued.text
            (job,) = wait_jobs(client, key, [queued.json()[0]["id"]])
            assert job["state"] == "done", job["error"]
        assert "Non-thread-safe" not in procs.log("server")
    finally:
        fleet.stop()


def test_sigterm_ends_the_server_itself_with_sqlite_let_go(tmp_path: Path) -> None:
    """uvicorn raised the SIGTERM again once it had stopped: the shell said "Terminated" and
    SQLite's -wal and -shm files stayed. The server ends itself, status 143, files gone."""
    config = tmp_path / "shop.toml"
    config.write_text('[server]\ndatabase = "sqlite:///opendnc.db"\n[library]\npath = "lib"\n')
    command = ["serve", "--config", str(config), "--bind", "127.0.0.1:0"]
    proc = subprocess.Popen(
        [sys.executable, "-m", "opendnc.cli.main", *command],
        cwd=tmp_path,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={"COLUMNS": "200", "PATH": "/usr/bin:/bin"},
    )
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()  # blocks until the server listens (or ends)
        assert line.startswith("opendnc server on http://127.0.0.1:"), line
        assert (tmp_path / "opendnc.db-wal").exists()  # the database is open in WAL mode
        proc.send_signal(signal.SIGTERM)
        _out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 143, err  # 128 + SIGTERM, ended by itself, not by the signal
    assert err == ""
    assert sorted(p.name for p in tmp_path.glob("opendnc.db*")) == [
        "opendnc.db",
        "opendnc.db.server-lock",
    ]
