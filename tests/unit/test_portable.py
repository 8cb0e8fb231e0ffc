"""The library without termios, fcntl, pty and tty (as on Windows): it imports and it works.

A child interpreter gets a meta-path finder that refuses those modules (and loses the Linux
socket options and ``poll()`` the TCP stream uses where they exist), imports every module
of the package except the pty-based simulators, then runs a TCP LSV2 session against the
virtual TNC (in a process of its own), XModem transfers over ``socket://`` and ``tcp://`` and
a drip-feed over ``socket://`` against loopback listeners here. pyserial's POSIX back end
needs termios, so the child also shows that none of this loads pyserial.
"""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys
import textwrap
from collections.abc import Iterator
from pathlib import Path

import pytest
from benchmarks.simproc import start_server

from opendnc.errors import PeerClosed, TransportTimeout
from opendnc.transport.base import ByteStream
from opendnc.xmodem.driver import receive, send
from opendnc.xmodem.framing import Mode
from tests.unit.xmodem.test_socket_port import _serve_once

# POSIX-only modules; the last three stand for the rest of what Windows lacks
BLOCKED = ("termios", "fcntl", "pty", "tty", "resource", "grp", "pwd")
# POSIX-only by design: the pty bench, the virtual cable, the simulators' serial front ends
POSIX_ONLY = (
    "opendnc.transport.pty",
    "opendnc.sim.cable",
    "opendnc.sim.haas.serial_front",
    "opendnc.sim.tnc.serial_front",  # the virtual TNC on a serial line can make its own pty
)

CHILD = textwrap.dedent(
    """
    import importlib, importlib.abc, json, pkgutil, sys
    from pathlib import Path

    blocked, posix_only = set(sys.argv[1].split(",")), tuple(sys.argv[2].split(","))

    class Refuse(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name.partition(".")[0] in blocked:
                raise ImportError(f"{name} is blocked (no such module on this platform)")
            return None

    sys.meta_path.insert(0, Refuse())
    for name in blocked:
        sys.modules.pop(name, None)
    # and the POSIX/Linux calls the transports use when they exist: without them the TCP
    # stream takes the path it takes on Windows (Python's socket timeouts, select(), no spin)
    import os, select, socket
    for module, attribute in [
        (socket, "MSG_DONTWAIT"), (socket, "SO_RCVTIMEO"), (socket, "SO_SNDTIMEO"),
        (select, "poll"), (os, "sched_yield"), (os, "sched_getaffinity"),
    ]:
        delattr(module, attribute)

    import opendnc

    imported, refused = [], {}
    def walk(package):
        # pkgutil.walk_packages would import the POSIX-only packages to look inside them
        for info in pkgutil.iter_modules(package.__path__, package.__name__ + "."):
            if any(info.name == p or info.name.startswith(p + ".") for p in posix_only):
                continue
            module = importlib.import_module(info.name)  # a failure fails the test
            imported.append(info.name)
            if info.ispkg:
                walk(module)
    walk(opendnc)

    from opendnc.lsv2 import Client
    from opendnc.xmodem.files import receive_file, send_file
    from opendnc.xmodem.framing import Mode

    tnc_port, send_port, recv_port, dnc_port, work = sys.argv[3:8]
    work = Path(work)
    with Client("127.0.0.1", int(tnc_port)) as tnc:
        program = b"0 BEGIN PGM PORTABLE MM\\r\\n1 END PGM PORTABLE MM\\r\\n"
        tnc.write_file("TNC:/PORTABLE.H", program)
        listing = [entry.name for entry in tnc.list_dir("TNC:/")]
        lsv2 = {
            "model": tnc.versions.model,
            "listed": "PORTABLE.H" in listing,
            "read_back": tnc.read_file("TNC:/PORTABLE.H").decode("latin-1"),
        }
    # random bytes: sent and received as a binary file, past the NC text check
    sent = send_file(
        f"socket://127.0.0.1:{send_port}", work / "out.nc", mode=Mode.ONE_K, binary=True
    )
    got = receive_file(
        f"tcp://127.0.0.1:{recv_port}", work / "in.nc", mode=Mode.CHECKSUM, binary=True
    )
    from opendnc.haas.dnc import DncConfig, stream_program
    dnc = stream_program(
        f"socket://127.0.0.1:{dnc_port}", work / "dnc.nc", safe_mode=False,
        config=DncConfig(chunk=32),
    )
    loaded = sorted(m for m in sys.modules if m.partition(".")[0] in blocked | {"serial"})
    for name in posix_only:
        try:
            importlib.import_module(name)
        except ImportError as exc:
            refused[name] = str(exc)
    from opendnc.transport import tcp
    print(json.dumps({
        "tcp_paths": [tcp._KERNEL_TIMEOUTS, tcp._CAN_SPIN],
        "imported": imported,
        "refused": refused,
        "loaded": loaded,
        "lsv2": lsv2,
        "sent": sent.size,
        "received": got.size,
        "dnc": [dnc.bytes_sent, dnc.xoffs, dnc.xons],
    }))
    """
)


@pytest.fixture
def tnc(tmp_path: Path) -> Iterator[int]:
    proc, port = start_server(tmp_path / "tnc", profile="tnc640")
    try:
        yield port
    finally:
        proc.terminate()
        proc.communicate(timeout=10)  # reaps it and closes its output pipe


def _control_in_dnc_mode(stream: ByteStream) -> bytes:
    """A control taking a drip-feed: one XOFF after the first bytes, the XON once the sender
    has stopped; everything until the sender hangs up."""
    got = bytearray()
    state = "running"
    while True:
        try:
            got += stream.read(4096)
        except TransportTimeout:
            if state == "paused":  # nothing came while paused: resume
                stream.write(b"\x11")
                state = "resumed"
            continue
        except PeerClosed:
            return bytes(got)
        if state == "running" and len(got) >= 64:
            stream.write(b"\x13")
            state = "paused"


def test_library_runs_without_termios_fcntl_pty(tnc: int, tmp_path: Path) -> None:
    outgoing = os.urandom(20_000)
    (tmp_path / "out.nc").write_bytes(outgoing)
    incoming = b"%\nO01234 (FROM THE CONTROL)\n" + b"G01 X1. Y2. F100.\n" * 300 + b"M30\n%\n"
    got = io.BytesIO()
    send_port, receiver = _serve_once(lambda stream: receive(stream, got, mode=Mode.ONE_K))
    recv_port, sender = _serve_once(lambda stream: send(stream, incoming, mode=Mode.CHECKSUM))
    program = b"%\nO00020 (DRIP)\n" + b"G01 X1. Y2. F100.\n" * 100 + b"M30\n%\n"
    (tmp_path / "dnc.nc").write_bytes(program)
    dnc_port, control = _serve_once(_control_in_dnc_mode)
    root = Path(__file__).resolve().parents[2]
    result = subprocess.run(
        [
            *(sys.executable, "-c", CHILD, ",".join(BLOCKED), ",".join(POSIX_ONLY)),
            *(str(tnc), str(send_port), str(recv_port), str(dnc_port), str(tmp_path)),
        ],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=root,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    report = json.loads(result.stdout.splitlines()[-1])
    receiver.outcome()
    sender.outcome()
    control.outcome()

    # the blocker worked: the POSIX-only modules were refused, nothing blocked got loaded
    assert sorted(report["refused"]) == sorted(POSIX_ONLY)
    assert report["loaded"] == []
    assert report["tcp_paths"] == [False, False]  # no kernel timeouts, no MSG_DONTWAIT spin
    # and everything else imported: the protocols, the CLI, the TCP simulator
    for name in ("opendnc.lsv2", "opendnc.haas.dnc", "opendnc.cli.main", "opendnc.sim.tnc"):
        assert name in report["imported"]
    assert report["lsv2"]["model"] == "TNC640"
    assert report["lsv2"]["listed"]
    assert report["lsv2"]["read_back"].startswith("0 BEGIN PGM PORTABLE MM")
    assert got.getvalue() == outgoing
    assert report["sent"] == len(outgoing)
    assert (tmp_path / "in.nc").read_bytes() == incoming
    assert report["received"] == len(incoming)
    assert control.result == program  # drip-fed over socket://, paused once, in order
    assert report["dnc"] == [len(program), 1, 1]
