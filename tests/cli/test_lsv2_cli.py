"""`opendnc lsv2` against the virtual TNC, as a user would run it (in-process and subprocess)."""

from __future__ import annotations

import contextlib
import json
import os
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from typer.testing import CliRunner

from opendnc.cli.main import app
from opendnc.sim.tnc import TncHandle, start_tnc

runner = CliRunner()


@pytest.fixture(scope="module")
def tnc(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TncHandle]:
    with start_tnc("tnc640", root=tmp_path_factory.mktemp("tnc")) as handle:
        yield handle


@pytest.fixture(scope="module")
def itnc(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TncHandle]:
    with start_tnc("itnc530", root=tmp_path_factory.mktemp("itnc")) as handle:
        yield handle


def cli(handle: TncHandle, *args: str, ok: bool = True) -> tuple[int, str, str]:
    """Run `opendnc lsv2 --port P ARGS` in-process; returns (exit code, stdout, stderr)."""
    result = runner.invoke(app, ["lsv2", "--port", str(handle.port), *args])
    if ok:
        assert result.exit_code == 0, (result.stdout, result.stderr, result.exception)
    return result.exit_code, result.stdout, result.stderr


def run_process(*args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    """Run `python -m opendnc.cli.main ARGS` as a real subprocess."""
    return subprocess.run(
        [sys.executable, "-m", "opendnc.cli.main", *args],
        capture_output=True,
        text=True,
        timeout=60,
        env={**os.environ, "COLUMNS": "80", **(env or {})},
    )


def remote_bytes(handle: TncHandle, path: str) -> bytes:
    """Read a file straight from the simulator's drive folder (wire path TNC:\\a\\b)."""
    drive, rest = path.split(":", 1)
    return handle.root.joinpath(
        drive, *[p for p in rest.replace("\\", "/").split("/") if p]
    ).read_bytes()


# -- info, ls, stat ------------------------------------------------------------------------


def test_info_json_subprocess(tnc: TncHandle) -> None:
    proc = run_process("lsv2", "--port", str(tnc.port), "info", "--json")
    assert proc.returncode == 0, proc.stderr
    info = json.loads(proc.stdout)
    assert info["control"] == "TNC640"
    assert info["family"] == "tnc_new"
    assert info["nc_version"] == "340595 11 SP4"
    assert info["plc_version"] == "17-M008-V01SP11"
    assert info["max_block_length"] == 4096
    assert info["buffer_size"] == 4096
    assert set(info) >= {"options", "secure_file_send", "system_info"}


def test_info_with_env_port_and_global_json(tnc: TncHandle) -> None:
    proc = run_process("lsv2", "--json", "info", env={"OPENDNC_LSV2_PORT": str(tnc.port)})
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["control"] == "TNC640"


def test_ls_json_lists_entries(tnc: TncHandle) -> None:
    _, out, _ = cli(tnc, "ls", "TNC:/nc_prog", "--json")
    entries = {e["name"]: e for e in json.loads(out)}
    assert entries["POCKET.H"]["size"] == len(remote_bytes(tnc, "TNC:/nc_prog/POCKET.H"))
    assert entries["POCKET.H"]["is_dir"] is False
    assert entries["demo"]["is_dir"] is True
    assert entries["POCKET.H"]["modified"].startswith("20")  # ISO 8601, named as in the table
    assert "mtime" not in entries["POCKET.H"]
    assert entries["POCKET.H"]["path"] == "TNC:/nc_prog/POCKET.H"  # as typed, with /


def test_ls_backslash_paths_and_table_output(tnc: TncHandle) -> None:
    _, out, _ = cli(tnc, "ls", "TNC:\\nc_prog\\demo")
    assert "CONTOUR.H" in out


def test_stat(tnc: TncHandle) -> None:
    _, out, _ = cli(tnc, "stat", "TNC:/nc_prog/POCKET.H", "--json")
    entry = json.loads(out)
    assert entry["path"] == "TNC:/nc_prog/POCKET.H"  # as typed
    assert entry["size"] > 0


# -- transfers -----------------------------------------------------------------------------


def test_put_get_binary_round_trip_subprocess(tnc: TncHandle, tmp_path: Path) -> None:
    data = os.urandom(50_000)
    (tmp_path / "blob.bin").write_bytes(data)
    port = str(tnc.port)
    up = run_process("lsv2", "--port", port, "put", str(tmp_path / "blob.bin"), "TNC:/rt/")
    assert up.returncode != 0
    assert "directory does not exist (55)" in up.stderr
    assert run_process("lsv2", "--port", port, "mkdir", "TNC:/rt").returncode == 0
    up = run_process("lsv2", "--port", port, "put", str(tmp_path / "blob.bin"), "TNC:/rt/")
    assert up.returncode == 0, up.stderr
    assert remote_bytes(tnc, "TNC:/rt/blob.bin") == data
    out = tmp_path / "back.bin"
    down = run_process("lsv2", "--port", port, "get", "TNC:\\rt\\blob.bin", str(out))
    assert down.returncode == 0, down.stderr
    assert out.read_bytes() == data


def test_put_get_ascii_round_trip(tnc: TncHandle, tmp_path: Path) -> None:
    text = b"0 BEGIN PGM T MM\r\n1 L X+1 R0 FMAX\r\n2 END PGM T MM\r\n"
    (tmp_path / "T.H").write_bytes(text)
    cli(tnc, "put", "--ascii", str(tmp_path / "T.H"), "TNC:/nc_prog/T.H")
    # ASCII mode: lines travel NUL-terminated, the control stores its own line ends
    assert b"1 L X+1 R0 FMAX" in remote_bytes(tnc, "TNC:/nc_prog/T.H")
    cli(tnc, "get", "--ascii", "TNC:/nc_prog/T.H", str(tmp_path / "back.h"))
    assert (tmp_path / "back.h").read_bytes() == text


def test_multi_file_get_and_put(tnc: TncHandle, tmp_path: Path) -> None:
    names = ["A.H", "B.H", "c.bin"]
    for i, name in enumerate(names):
        (tmp_path / name).write_bytes(f"0 BEGIN PGM {i} MM\r\n".encode() * (i + 1) * 300)
    cli(tnc, "mkdir", "TNC:/multi")
    _, out, _ = cli(tnc, "put", *(str(tmp_path / n) for n in names), "TNC:/multi")
    assert out.count("put ") == 3
    got = tmp_path / "got"
    got.mkdir()
    cli(tnc, "get", *(f"TNC:/multi/{n}" for n in names), str(got))
    for name in names:
        assert (got / name).read_bytes() == (tmp_path / name).read_bytes()
    # several sources need an existing folder as destination
    code, _, err = cli(
        tnc, "get", "TNC:/multi/A.H", "TNC:/multi/B.H", str(tmp_path / "no"), ok=False
    )
    assert code == 1
    assert "existing folder" in err


def test_mkdir_cp_mv_rm_rmdir(tnc: TncHandle, tmp_path: Path) -> None:
    (tmp_path / "F.H").write_bytes(b"0 BEGIN PGM F MM\r\n1 END PGM F MM\r\n")
    cli(tnc, "mkdir", "TNC:/ops/sub")
    cli(tnc, "put", str(tmp_path / "F.H"), "TNC:/ops/sub/F.H")
    cli(tnc, "cp", "TNC:/ops/sub/F.H", "TNC:/ops/G.H")
    cli(tnc, "mv", "TNC:/ops/G.H", "TNC:/ops/sub/H.H")
    _, out, _ = cli(tnc, "ls", "TNC:/ops/sub", "--json")
    assert sorted(e["name"] for e in json.loads(out)) == ["F.H", "H.H"]
    code, _, err = cli(tnc, "rmdir", "TNC:/ops/sub", ok=False)
    assert code == 1
    assert "(54)" in err
    cli(tnc, "rm", "TNC:/ops/sub/F.H")
    cli(tnc, "rm", "TNC:\\ops\\sub\\H.H")
    cli(tnc, "rmdir", "TNC:/ops/sub")
    _, out, _ = cli(tnc, "ls", "TNC:/ops", "--json")
    assert json.loads(out) == []


# -- backup and sync -----------------------------------------------------------------------


def test_backup_then_rerun_skips_everything(tnc: TncHandle, tmp_path: Path) -> None:
    _, out, _ = cli(tnc, "backup", "TNC:/nc_prog", str(tmp_path / "bk"), "--json")
    first = json.loads(out)
    assert first["failed"] == []
    assert len(first["copied"]) >= 5
    assert first["skipped"] == []
    pocket = tmp_path / "bk" / "POCKET.H"
    assert pocket.read_bytes() == remote_bytes(tnc, "TNC:/nc_prog/POCKET.H")
    assert (tmp_path / "bk" / "demo" / "CONTOUR.H").is_file()
    _, out, _ = cli(tnc, "backup", "TNC:/nc_prog", str(tmp_path / "bk"), "--json")
    second = json.loads(out)
    assert second["copied"] == []
    assert sorted(second["skipped"]) == sorted(first["copied"])
    assert second["bytes"] == 0
    # a changed local copy is fetched again
    pocket.write_bytes(b"changed")
    _, out, _ = cli(tnc, "backup", "TNC:/nc_prog", str(tmp_path / "bk"), "--json")
    assert json.loads(out)["copied"] == ["TNC:/nc_prog/POCKET.H"]
    assert pocket.read_bytes() == remote_bytes(tnc, "TNC:/nc_prog/POCKET.H")


class CuttingProxy:
    """Loopback TCP proxy that drops the link after ``limit`` bytes from the server."""

    def __init__(self, port: int, limit: int) -> None:
        self.limit = limit
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.port = self.listener.getsockname()[1]
        self.target = port
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self) -> None:
        client, _ = self.listener.accept()
        server = socket.create_connection(("127.0.0.1", self.target))
        passed = 0

        def upstream() -> None:
            try:
                while data := client.recv(65536):
                    server.sendall(data)
            except OSError:
                pass

        threading.Thread(target=upstream, daemon=True).start()
        try:
            while passed < self.limit and (data := server.recv(65536)):
                data = data[: self.limit - passed]
                client.sendall(data)
                passed += len(data)
        finally:
            # shutdown first: a plain close would wait for the upstream thread's recv
            for sock in (client, server):
                with contextlib.suppress(OSError):
                    sock.shutdown(socket.SHUT_RDWR)
                sock.close()
            self.listener.close()


def test_interrupted_backup_leaves_no_partial_file(tnc: TncHandle, tmp_path: Path) -> None:
    big = os.urandom(300_000)
    tnc.root.joinpath("TNC", "cut").mkdir()
    tnc.root.joinpath("TNC", "cut", "big.bin").write_bytes(big)
    tnc.root.joinpath("TNC", "cut", "a_small.h").write_bytes(b"0 BEGIN PGM S MM\r\n")
    proxy = CuttingProxy(tnc.port, 100_000)  # dies a third into big.bin
    target = tmp_path / "bk"
    proc = run_process("lsv2", "--port", str(proxy.port), "backup", "TNC:/cut", str(target))
    assert proc.returncode == 1
    assert len(proc.stderr.strip().splitlines()) == 1
    assert "error:" in proc.stderr
    left = sorted(p.name for p in target.rglob("*"))
    assert "big.bin" not in left
    assert not [n for n in left if n.endswith(".part")], left
    # the re-run completes it
    _, _out, _ = cli(tnc, "backup", "TNC:/cut", str(target), "--json")
    assert (target / "big.bin").read_bytes() == big


def test_killed_backup_leaves_no_partial_file(tmp_path: Path) -> None:
    with start_tnc("tnc640", root=tmp_path / "tnc", latency=0.004) as slow:
        big = os.urandom(400_000)  # ~100 blocks at 4 ms each
        slow.root.joinpath("TNC", "kill").mkdir()
        slow.root.joinpath("TNC", "kill", "big.bin").write_bytes(big)
        target = tmp_path / "bk"
        command = [sys.executable, "-m", "opendnc.cli.main", "lsv2", "--port", str(slow.port)]
        proc = subprocess.Popen(
            [*command, "backup", "TNC:/kill", str(target)],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        try:
            deadline = time.monotonic() + 30
            while not list(target.glob(".*part")) and time.monotonic() < deadline:
                time.sleep(0.005)
            proc.kill()  # SIGKILL: no cleanup code runs in the client
            proc.wait(10)
            assert list(target.glob(".*part")), "killed before the download started"
        finally:
            if proc.poll() is None:
                proc.kill()
        assert not (target / "big.bin").exists()  # never a partial file under the real name
        cli(slow, "backup", "TNC:/kill", str(target))
        assert (target / "big.bin").read_bytes() == big
        assert sorted(p.name for p in target.iterdir()) == ["big.bin"]  # stale temps removed


def test_sync_pushes_only_changes(tnc: TncHandle, tmp_path: Path) -> None:
    src = tmp_path / "src"
    (src / "sub").mkdir(parents=True)
    (src / "ONE.H").write_bytes(b"0 BEGIN PGM ONE MM\r\n")
    (src / "sub" / "TWO.H").write_bytes(b"0 BEGIN PGM TWO MM\r\n")
    _, out, _ = cli(tnc, "sync", str(src), "TNC:/synced", "--json")
    first = json.loads(out)
    # printed in the separator style typed on the command line
    assert sorted(first["copied"]) == ["TNC:/synced/ONE.H", "TNC:/synced/sub/TWO.H"]
    assert remote_bytes(tnc, "TNC:/synced/sub/TWO.H") == b"0 BEGIN PGM TWO MM\r\n"
    _, out, _ = cli(tnc, "sync", str(src), "TNC:/synced", "--json")
    assert json.loads(out)["copied"] == []
    (src / "sub" / "TWO.H").write_bytes(b"0 BEGIN PGM TWO MM\r\n1 L X+5\r\n")
    (src / "THREE.H").write_bytes(b"3")
    _, out, _ = cli(tnc, "sync", str(src), "TNC:/synced", "--json")
    third = json.loads(out)
    assert sorted(third["copied"]) == ["TNC:/synced/THREE.H", "TNC:/synced/sub/TWO.H"]
    assert third["skipped"] == ["TNC:/synced/ONE.H"]
    _, out, _ = cli(tnc, "sync", str(src), "TNC:\\synced", "--json")
    assert json.loads(out)["skipped"][0].startswith("TNC:\\synced\\")


# -- machine data --------------------------------------------------------------------------


def test_status_json_and_table(tnc: TncHandle) -> None:
    _, out, _ = cli(tnc, "status", "--json")
    status = json.loads(out)
    assert status["execution_mode"] == "manual"
    assert status["program_state"] == "idle"
    # the wire's 10000 (0.01 % units) is 100 %
    percent = {"feed_percent": 100, "spindle_percent": 100, "rapid_percent": 100}
    assert status["overrides"] == percent
    assert status["axes"]["Z"] == "250.0000"
    assert status["tool"] is None  # TNC 640 has no tool selector: n/a, not a crash
    _, out, _ = cli(tnc, "status")
    assert "feed 100 %" in out
    assert "n/a" in out
    assert "manual" in out


def test_status_itnc_has_tool(itnc: TncHandle) -> None:
    _, out, _ = cli(itnc, "--json", "status")
    assert json.loads(out)["tool"] is not None


@pytest.mark.parametrize(
    ("operand", "count", "expected"),
    [("W4", "2", [("W4", 10000), ("W6", 0)]), ("M100", "2", [("M100", False), ("M101", False)])],
)
def test_plc_read(
    tnc: TncHandle, operand: str, count: str, expected: list[tuple[str, object]]
) -> None:
    _, out, _ = cli(tnc, "plc", "read", operand, count, "--json")
    assert [(v["operand"], v["value"]) for v in json.loads(out)] == expected


def test_plc_read_dword_matches_simulator(tnc: TncHandle) -> None:
    _, out, _ = cli(tnc, "plc", "read", "D8", "--json")
    assert json.loads(out) == [{"operand": "D8", "value": 0}]
    code, _, err = cli(tnc, "plc", "read", "X1", ok=False)
    assert code == 1
    assert "not a PLC operand" in err


def test_param_get_and_set_needs_unsafe(tmp_path: Path) -> None:
    with start_tnc("tnc640", root=tmp_path) as own:
        name = "CfgDisplayLanguage.ncLanguage"
        _, out, _ = cli(own, "param", "get", name, "--json")
        assert json.loads(out) == {"name": name, "value": "ENGLISH"}
        code, out, err = cli(own, "param", "set", name, "GERMAN", ok=False)
        assert code == 1
        assert "--unsafe" in err
        assert len(err.strip().splitlines()) == 1
        _, out, _ = cli(own, "param", "get", name)
        assert out.strip() == "ENGLISH"
        cli(own, "--unsafe", "param", "set", name, "GERMAN")
        _, out, _ = cli(own, "param", "get", name)
        assert out.strip() == "GERMAN"


def test_errors_na_on_tnc640_and_list_on_itnc(tnc: TncHandle, itnc: TncHandle) -> None:
    _, out, _ = cli(tnc, "errors", "--json")
    assert json.loads(out) == {"supported": False, "errors": []}
    _, out, _ = cli(itnc, "errors", "--json")
    listed = json.loads(out)
    assert listed["supported"] is True
    # the virtual iTNC reports one class-3 message (docs/lsv2-nc-error-classes.md: program halt)
    assert listed["errors"][0]["class_number"] == 3
    assert listed["errors"][0]["class"] == "program halt"
    _, out, _ = cli(itnc, "errors")
    assert out.startswith("program halt (group ")
    assert str(listed["errors"][0]["number"]) not in out  # not as a signed integer


def test_data_read_and_scope_channels_on_itnc(itnc: TncHandle) -> None:
    _, out, _ = cli(itnc, "data", "read", "/TABLE/TOOL/T/1/L", "--json")
    assert json.loads(out)["path"] == "/TABLE/TOOL/T/1/L"
    _, out, _ = cli(itnc, "scope", "channels", "--json")
    assert len(json.loads(out)) > 0


def test_scope_record_csv(itnc: TncHandle, tmp_path: Path) -> None:
    out = tmp_path / "scope.csv"
    cli(itnc, "scope", "record", str(out), "-s", "0:0", "-s", "0:2", "--blocks", "2")
    rows = out.read_text().splitlines()
    assert rows[0] == "time_us,s actual X [mm],s actual Z [mm]"
    assert len(rows) == 1 + 64
    assert rows[2].startswith("21000,")


@pytest.mark.parametrize(("suffix", "magic"), [(".bmp", b"BM"), (".png", b"\x89PNG\r\n\x1a\n")])
def test_screenshot(tnc: TncHandle, tmp_path: Path, suffix: str, magic: bytes) -> None:
    out = tmp_path / f"screen{suffix}"
    cli(tnc, "screenshot", str(out))
    assert out.read_bytes().startswith(magic)


def test_table_get_csv_and_json(tnc: TncHandle, tmp_path: Path) -> None:
    cli(tnc, "table", "get", "TNC:/table/tool.t", str(tmp_path / "tool.csv"))
    lines = (tmp_path / "tool.csv").read_text().splitlines()
    assert lines[0].startswith("T,NAME,L,R")
    assert lines[2].startswith("1,")
    cli(tnc, "table", "get", "TNC:/table/tool.t", str(tmp_path / "tool.json"))
    table = json.loads((tmp_path / "tool.json").read_text())
    assert table["name"] == "TOOL.T"
    assert len(table["rows"]) == len(lines) - 1


def test_table_get_to_stdout(tnc: TncHandle) -> None:
    _, out, _ = cli(tnc, "table", "get", "TNC:\\table\\tool.t", "-")
    rows = json.loads(out)["rows"]
    assert rows[1]["NAME"] == "MILL_D10_ROUGH"


def test_operations_log(tnc: TncHandle, tmp_path: Path) -> None:
    cli(tnc, "ls", "TNC:/nc_prog")  # a folder change on another session must not matter
    cli(tnc, "log", str(tmp_path / "op.log"))
    assert (tmp_path / "op.log").read_bytes().startswith(b"Operation Logbook")


# -- failures ------------------------------------------------------------------------------


def test_missing_file_is_one_line_error_subprocess(tnc: TncHandle, tmp_path: Path) -> None:
    proc = run_process("lsv2", "--port", str(tnc.port), "get", "TNC:\\nope.h", str(tmp_path))
    assert proc.returncode == 1
    assert proc.stderr.strip() == "error: get TNC:\\nope.h: file not found (32)"
    assert not list(tmp_path.iterdir())


def test_closed_port_is_one_line_error_subprocess() -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]  # bound but not listening: connection refused
        proc = run_process("lsv2", "--port", str(port), "--timeout", "2", "info")
    assert proc.returncode == 1
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1
    assert lines[0].startswith("error: ")
    assert str(port) in lines[0]
