"""The `opendnc haas`, `opendnc dprnt` and `opendnc sim haas` commands end to end."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

from typer.testing import CliRunner

from opendnc.cli.main import app
from opendnc.haas.mdc_client import MdcClient
from opendnc.sim.haas import SimHaasThread

runner = CliRunner()


def mdc_port(sim: SimHaasThread) -> str:
    assert sim.sim is not None
    assert sim.sim.mdc is not None
    return str(sim.sim.mdc.port)


def test_q_json_and_text(sim: SimHaasThread) -> None:
    port = mdc_port(sim)
    result = runner.invoke(app, ["haas", "q", "Q500", "--port", port, "--json"])
    assert result.exit_code == 0, result.output
    doc = json.loads(result.stdout)
    assert doc["command"] == "Q500"
    assert doc["type"] == "ProgramStatus"
    assert doc["fields"] == {"program": "MDI", "status": "IDLE", "parts": 0}
    assert doc["raw"] == "PROGRAM, MDI, IDLE, PARTS, 0"
    result = runner.invoke(app, ["haas", "q", "Q102", "--port", port])
    assert result.stdout.strip() == "MODEL, VF-2"
    result = runner.invoke(app, ["haas", "q", "Q600", "--port", port])
    assert result.exit_code == 1
    assert "needs a variable" in result.output


def test_status_and_macros(sim: SimHaasThread) -> None:
    port = mdc_port(sim)
    result = runner.invoke(app, ["haas", "status", "--port", port, "--json"])
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout)["model"] == "VF-2"
    result = runner.invoke(app, ["haas", "status", "--port", port])
    assert "Serial number" in result.stdout
    refused = runner.invoke(app, ["haas", "macro", "set", "10100", "2.5", "--port", port])
    assert refused.exit_code == 1
    assert "locked" in refused.output
    ok = runner.invoke(app, ["haas", "macro", "set", "10100", "2.5", "--port", port, "--unsafe"])
    assert ok.exit_code == 0, ok.output
    got = runner.invoke(app, ["haas", "macro", "get", "10100", "--port", port, "--json"])
    assert json.loads(got.stdout) == {"var": 10100, "value": 2.5}
    offset = ["haas", "macro", "set", "5223", "-1", "--port", port, "--unsafe"]
    assert runner.invoke(app, offset).exit_code == 1
    assert runner.invoke(app, [*offset, "--any-variable"]).exit_code == 0
    got = runner.invoke(app, ["haas", "macro", "get", "5223", "--port", port])
    assert got.stdout.strip() == "#5223 = -1"


def test_q_connection_refused_is_one_line_error() -> None:
    result = runner.invoke(app, ["haas", "q", "Q100", "--port", "1", "--timeout", "1"])
    assert result.exit_code == 1
    assert "cannot connect" in result.output


def test_dprnt_listen_cli(sim: SimHaasThread, tmp_path: Path) -> None:
    assert sim.sim is not None
    assert sim.sim.dprnt_tcp is not None
    out = sim.sim.dprnt_tcp
    csv_path, jsonl_path = tmp_path / "d.csv", tmp_path / "d.jsonl"
    args = ["dprnt", "listen", "--port", f"tcp://127.0.0.1:{out.port}", "--max-lines", "5"]
    args += ["--csv", str(csv_path), "--jsonl", str(jsonl_path), "--json"]
    result: list[object] = []
    thread = threading.Thread(target=lambda: result.append(runner.invoke(app, args)))
    thread.start()
    deadline = time.monotonic() + 5
    while not sim.call(lambda: len(out.readers)):
        assert time.monotonic() < deadline
        time.sleep(0.01)
    control = sim.sim.control
    sim.call(lambda: control.start_program(321))
    thread.join(10)
    assert not thread.is_alive()
    records = [json.loads(line) for line in jsonl_path.read_text().splitlines()]
    assert [r["line"] for r in records][-1] == "   DONE   "
    assert records[0]["numbers"] == [0.0, 0.0, -1.25]
    assert csv_path.read_text().count("\n") == 6  # header + 5 lines


def test_share_push_to_folder(tmp_path: Path) -> None:
    src = tmp_path / "O00007.nc"
    src.write_text("%\nO00007\nM30\n%\n")
    dest = tmp_path / "share"
    dest.mkdir()
    result = runner.invoke(app, ["haas", "share", "push", str(src), "--to", str(dest), "--json"])
    assert result.exit_code == 0, result.output
    assert (dest / "O00007.nc").read_text() == src.read_text()


def test_sim_haas_process(tmp_path: Path) -> None:
    (tmp_path / "O00001.nc").write_text("%\nO00001\nT7 M06\nM30\n%\n")
    cmd = [sys.executable, "-m", "opendnc.cli.main", "sim", "haas", "--root", str(tmp_path)]
    cmd += ["--mdc-port", "0", "--control", "classic", "--model", "VF-4", "--run", "1"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        assert line.startswith("MDC 127.0.0.1:"), line + (proc.stderr.read() if proc.stderr else "")
        port = int(line.rsplit(":", 1)[1])
        with MdcClient("127.0.0.1", port) as client:
            deadline = time.monotonic() + 5
            while client.query(201).to_payload() != "USING TOOL, 7":
                assert time.monotonic() < deadline
                time.sleep(0.02)
            assert client.query(102).to_payload() == "MODEL, VF-4"
            assert client.query(104).to_payload() == "MODE, (MEM)"
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(10)
        for stream in (proc.stdout, proc.stderr):
            if stream is not None:
                stream.close()


def test_sim_haas_bad_serial_port_and_surface_are_one_line_errors(tmp_path: Path) -> None:
    missing = tmp_path / "no-such-tty"
    result = runner.invoke(app, ["sim", "haas", "--root", str(tmp_path), "--serial", str(missing)])
    assert result.exit_code == 1
    assert "cannot open serial port" in result.output
    assert "Traceback" not in result.output
    bad = runner.invoke(app, ["sim", "haas", "--root", str(tmp_path), "--surface", "cone:1"])
    assert bad.exit_code == 1
    assert "bad surface" in bad.output
