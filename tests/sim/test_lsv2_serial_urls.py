"""`opendnc lsv2 --serial socket://…` and `rfc2217://…`: the control's line behind a serial server.

The virtual TNC 320 serves serial LSV2 on one end of `opendnc sim cable` (115200 baud, 8E1
timing); a serial device server holds the other end and the client reaches it over TCP:

* ``socket://`` — socat in raw TCP mode (``TCP-LISTEN`` to the device), as a device server
  without RFC 2217; the client's line settings do not travel, the server's port has its own.
* ``rfc2217://`` — pyserial's RFC 2217 ``PortManager`` over the device
  (:mod:`tests.sim.rfc2217_server`): the client's baud rate and parity are sent to the server,
  which applies them to its port.

Neither kind of server can mark parity errors for the client (docs/lsv2-serial.md, "Parity
errors"); on a clean line the answers equal those over TCP and files travel byte-identical.
"""

from __future__ import annotations

import contextlib
import json
import os
import queue
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from opendnc.sim.cable import CableProcess
from opendnc.sim.tnc import TncHandle, start_tnc
from opendnc.sim.tnc.serial_front import attach_serial
from tests.peers import require_command
from tests.sim.lsv2_cli import lsv2_ok, lsv2_over_tcp

BAUD = 115200
# pyserial's RFC 2217 client names its reader thread with the deprecated setName() and setDaemon()
pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning:serial.rfc2217")
REPO = Path(__file__).resolve().parents[2]


@dataclass
class Bench:
    tnc: TncHandle
    url: str
    server: subprocess.Popen[str]


_LINES: dict[tuple[int, str], queue.Queue[str]] = {}


def _lines(proc: subprocess.Popen[str], stream_name: str) -> queue.Queue[str]:
    """The stream's lines as a thread reads them. (``select`` on the pipe would miss a line
    that an earlier ``readline`` already pulled into the text buffer: the settings line often
    comes in the same read as the one before it.)"""
    key = (proc.pid, stream_name)
    if key not in _LINES:
        stream = proc.stdout if stream_name == "stdout" else proc.stderr
        assert stream is not None
        lines: queue.Queue[str] = queue.Queue()

        def pump() -> None:
            # the test closes the pipe when it stops the process: the end of the stream too
            with contextlib.suppress(ValueError, OSError):
                for line in stream:
                    lines.put(line)
            lines.put("")  # the end of the stream

        threading.Thread(target=pump, daemon=True).start()
        _LINES[key] = lines
    return _LINES[key]


def _wait_line(proc: subprocess.Popen[str], stream_name: str, marker: str) -> str:
    lines = _lines(proc, stream_name)
    deadline = time.monotonic() + 15
    while (left := deadline - time.monotonic()) > 0:
        try:
            line = lines.get(timeout=left)
        except queue.Empty:
            break
        assert line, f"{proc.args!r} ended before it listened"
        if marker in line:
            return line
    raise AssertionError(f"{proc.args!r} did not print {marker!r} within 15 s")


def _socat(device: str) -> tuple[subprocess.Popen[str], str]:
    socat = require_command("socat")
    with __import__("socket").create_server(("127.0.0.1", 0)) as probe:
        port = int(probe.getsockname()[1])
    proc = subprocess.Popen(
        [
            socat,
            "-d",
            "-d",
            # a connection's child lets go of the device at once when its client leaves, so
            # the next one's answers are not read by a child on its way out
            "-t",
            "0",
            f"TCP-LISTEN:{port},bind=127.0.0.1,reuseaddr,fork",
            f"FILE:{device},raw,echo=0",
        ],
        stderr=subprocess.PIPE,
        text=True,
    )
    _wait_line(proc, "stderr", "listening on")
    return proc, f"socket://127.0.0.1:{port}"


def _rfc2217(device: str) -> tuple[subprocess.Popen[str], str]:
    proc = subprocess.Popen(
        [sys.executable, "-m", "tests.sim.rfc2217_server", device],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=REPO,
        env={**os.environ, "PYTHONPATH": str(REPO)},
    )
    port = _wait_line(proc, "stdout", "listening").split()[1]
    return proc, f"rfc2217://127.0.0.1:{port}"


@pytest.fixture(scope="module", params=["socket", "rfc2217"])
def bench(
    request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[Bench]:
    with (
        CableProcess(baud=BAUD, bits_per_char=11) as cable,
        start_tnc("tnc320", root=tmp_path_factory.mktemp(request.param)) as tnc,
    ):
        attach_serial(tnc, cable.path_a, baud=BAUD)
        server, url = (_socat if request.param == "socket" else _rfc2217)(cable.path_b)
        try:
            yield Bench(tnc, url, server)
        finally:
            server.terminate()
            server.communicate(timeout=10)


def over_serial(bench: Bench, *args: str) -> str:
    return lsv2_ok("--serial", bench.url, "--baud", str(BAUD), "--timeout", "20", *args)


def over_tcp(bench: Bench, *args: str) -> str:
    return lsv2_over_tcp(bench.tnc, *args)


def test_info_and_ls_through_the_serial_server_match_tcp(bench: Bench) -> None:
    info = json.loads(over_serial(bench, "info", "--json"))
    assert info["control"] == bench.tnc.profile.model
    tcp = json.loads(over_tcp(bench, "info", "--json"))
    # over serial the CLI asks for 256-byte telegrams unless --telegram-size says otherwise
    # (docs/lsv2-serial.md, "Telegram size"); over TCP for the most the control allows
    assert info.pop("buffer_size") == 256
    assert tcp.pop("buffer_size") >= 1024
    assert info == tcp
    listing = json.loads(over_serial(bench, "ls", "TNC:/", "--json"))
    assert listing == json.loads(over_tcp(bench, "ls", "TNC:/", "--json"))
    if bench.url.startswith("rfc2217://"):
        # RFC 2217 carried the client's baud rate and 8E1 to the server's port (socket://
        # has no such channel: the device server's own settings apply). The options may
        # arrive in separate segments, so a half-applied line (new baud, old parity) can
        # come first: what counts is that the full setting is reached.
        wanted = f"settings {BAUD} 8E1"
        assert _wait_line(bench.server, "stdout", wanted) == wanted + "\n"


def test_put_and_get_through_the_serial_server_byte_identical(bench: Bench, tmp_path: Path) -> None:
    blob = os.urandom(3000) + b"\x10\x10\x03\x05\x04\x15"  # stuffing and link characters
    text = b"".join(b"%d L X+%d.5 R0 F500\r\n" % (i, i) for i in range(150))
    (tmp_path / "u.bin").write_bytes(blob)
    (tmp_path / "U.H").write_bytes(text)
    over_serial(bench, "put", str(tmp_path / "u.bin"), "TNC:/u.bin")
    over_serial(bench, "put", "--ascii", str(tmp_path / "U.H"), "TNC:/U.H")
    assert (bench.tnc.root / "TNC" / "u.bin").read_bytes() == blob
    over_tcp(bench, "get", "--ascii", "TNC:/U.H", str(tmp_path / "tcp.h"))
    assert (tmp_path / "tcp.h").read_bytes() == text
    over_serial(bench, "get", "TNC:/u.bin", str(tmp_path / "back.bin"))
    over_serial(bench, "get", "--ascii", "TNC:/U.H", str(tmp_path / "back.h"))
    assert (tmp_path / "back.bin").read_bytes() == blob
    assert (tmp_path / "back.h").read_bytes() == text
