"""`opendnc sim tnc` as a process, --trace output, latency, the asyncio API and the DNC option."""

from __future__ import annotations

import asyncio
import io
import re
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

from opendnc.lsv2.framing import Frame, TelegramFramer
from opendnc.sim.tnc import TraceHook, serve_tnc, start_tnc


def _ask(sock: socket.socket, name: str, payload: bytes = b"") -> Frame:
    sock.sendall(TelegramFramer.encode(Frame(name, payload)))
    framer = TelegramFramer()
    while (frame := framer.next_frame()) is None:
        data = sock.recv(65536)
        assert data, "server closed"
        framer.feed(data)
    return frame


def test_cli_serves_until_terminated(tmp_path: Path) -> None:
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "opendnc.cli.main",
            "sim",
            "tnc",
            "--port",
            "0",
            "--profile",
            "itnc530",
            "--root",
            str(tmp_path),
            "--trace",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        port = int(re.search(r"listening on 127\.0\.0\.1:(\d+)", line).group(1))  # type: ignore[union-attr]
        assert f"root: {tmp_path}" in proc.stdout.readline()
        with socket.create_connection(("127.0.0.1", port), timeout=5) as sock:
            assert _ask(sock, "A_LG", b"INSPECT\0").mnemonic == "T_OK"
            reply = _ask(sock, "R_VR")
            assert reply.payload.startswith(b"iTNC530")
        assert (tmp_path / "TNC" / "TOOL.T").exists()
    finally:
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=10)
    assert proc.returncode == 0
    assert "stopped" in out
    assert (tmp_path / ".state" / "machine.json").exists()  # state saved on the way out
    assert "<- Login(login='INSPECT'" in err
    assert "41 5f 4c 47" in err  # hex of A_LG
    assert "-> VersionReply" in err


def test_cli_rejects_unknown_profile() -> None:
    result = subprocess.run(
        [sys.executable, "-m", "opendnc.cli.main", "sim", "tnc", "--profile", "tnc999"],
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert result.returncode == 1
    assert "unknown profile" in result.stderr


def test_latency_delays_each_telegram(tmp_path: Path) -> None:
    with (
        start_tnc("tnc320", root=tmp_path, latency=0.05) as tnc,
        socket.create_connection(("127.0.0.1", tnc.port), timeout=5) as sock,
    ):
        t0 = time.perf_counter()
        for _ in range(4):
            _ask(sock, "A_LG", b"INSPECT\0")
        assert time.perf_counter() - t0 >= 0.2


def test_trace_hook_and_asyncio_api(tmp_path: Path) -> None:
    out = io.StringIO()

    async def scenario() -> None:
        server = await serve_tnc("tnc620", root=tmp_path, port=0, trace=TraceHook(out))
        try:
            reader, writer = await asyncio.open_connection("127.0.0.1", server.port)
            writer.write(TelegramFramer.encode(Frame("A_LG", b"FILE\0")))
            await writer.drain()
            assert (await reader.readexactly(8))[4:] == b"T_OK"
            writer.close()
            await writer.wait_closed()
        finally:
            await server.close()

    asyncio.run(scenario())
    text = out.getvalue()
    assert "<- Login(login='FILE'" in text
    assert "-> Ok()" in text


def test_dnc_login_needs_the_option(tmp_path: Path) -> None:
    with (
        start_tnc("tnc640", root=tmp_path, dnc_option=False) as tnc,
        socket.create_connection(("127.0.0.1", tnc.port), timeout=5) as sock,
    ):
        assert _ask(sock, "A_LG", b"INSPECT\0").mnemonic == "T_OK"
        assert _ask(sock, "A_LG", b"DNC\0").payload == b"\x01\x31"  # 49: login not possible
        assert _ask(sock, "R_CI", b"\0\0\0\x02").payload == b"\0\0\0\x01\0\0\0\0"


def test_dnc_select_and_key_start_run_a_program(tmp_path: Path) -> None:
    with (
        start_tnc("tnc640", root=tmp_path) as tnc,
        socket.create_connection(("127.0.0.1", tnc.port), timeout=5) as sock,
    ):
        for login in (b"INSPECT", b"DNC", b"MONITOR"):
            assert _ask(sock, "A_LG", login + b"\0").mnemonic == "T_OK"
        tnc.call(lambda c: setattr(c.machine, "block_time", 0.01))
        assert _ask(sock, "C_NC", b"TNC:\\nc_prog\\1001.I\0").mnemonic == "T_OK"
        assert _ask(sock, "C_EK", b"\x01\xc3").mnemonic == "T_OK"  # full sequence
        assert _ask(sock, "C_EK", b"\x00\xf0").mnemonic == "T_OK"  # NC start
        assert _ask(sock, "R_RI", b"\x00\x1a").payload == b"\x00\x00"  # started
        # the selected program cannot be deleted while selected
        assert _ask(sock, "A_LG", b"FILE\0").mnemonic == "T_OK"
        assert _ask(sock, "C_FD", b"TNC:\\nc_prog\\1001.I\0").payload == b"\x01\x24"
        deadline = time.monotonic() + 10
        while (state := _ask(sock, "R_RI", b"\x00\x1a").payload) == b"\x00\x00":
            assert time.monotonic() < deadline, "program still running"
            time.sleep(0.01)
        assert state == b"\x00\x02"  # finished
        assert tnc.call(lambda c: c.machine.part_counter) == 1
