"""What the server does to a serial Haas is its state: a control without MDC tells nothing,
so through a drip-feed it read "unknown" while it cut. A drip-feed is the machine running; a
load into a silent control has it waiting on the transfer (ready); a drip-feed that breaks
leaves an alarm with its text, one a person cancels a stopped program.

The feed goes to a real peer: a TCP serial server on loopback (``socket://``) that takes
part of the program and hangs up, as a terminal server does when its line drops."""

from __future__ import annotations

import asyncio
import socket
import threading
from datetime import UTC, datetime
from pathlib import Path

import pytest

from opendnc.errors import DncError
from opendnc.server.config.shop import parse_config
from opendnc.server.core.jobwords import JobKind
from opendnc.server.core.state import State, classify
from opendnc.server.core.status import MachineStatus
from opendnc.server.jobs.executors import JobCancelled
from opendnc.server.kinds.registry import connector_for
from opendnc.server.machines.state import MachineState

PROGRAM = (
    b"%\nO03000 (LONG)\n" + b"".join(b"G01 X%d. F30.\n" % i for i in range(4000)) + b"M30\n%\n"
)


def _config(tmp_path: Path, serial: str) -> str:
    return (
        f'[[machines]]\nname = "vf2"\nkind = "haas_serial"\nserial = "{serial}"\n'
        'dripfeed = true\nserial_profile = { baud = 115200, flow = "none" }\n'
    )


def test_a_drip_feed_is_running_and_a_load_into_a_silent_control_is_ready(tmp_path: Path) -> None:
    config = parse_config(_config(tmp_path, "socket://127.0.0.1:9"), base=tmp_path).machines[0]
    state = MachineState(config, online=True)
    # the port opens; the control says nothing
    state.set_status(MachineStatus(at=datetime.now(UTC), available=True))
    assert state.as_json()["state"] == "unknown"
    state.start_job(7, len(PROGRAM), JobKind.DRIPFEED, "O03000.nc")
    assert state.as_json()["state"] == "running"
    event = state.event()
    assert classify(event.status, online=True) is State.RUNNING  # what the timeline records
    assert event.status is not None
    assert event.status.program == "O03000.nc"
    state.job_id = None  # the feed ended: the control's own (lack of) word again
    assert state.as_json()["state"] == "unknown"
    state.start_job(8, len(PROGRAM), JobKind.SEND, "O01000.nc")
    assert state.as_json()["state"] == "ready"
    assert state.as_json()["status"]["message"] == "loading O01000.nc"
    state.job_id = None
    state.online = False  # a job on a machine gone offline does not make it look alive
    state.start_job(9, 1, JobKind.DRIPFEED, "O03000.nc")
    assert state.as_json()["state"] == "offline"


class _Line:
    """A TCP serial server on loopback that takes ``keep`` bytes of a feed, then hangs up."""

    def __init__(self, keep: int) -> None:
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.port = self.listener.getsockname()[1]
        self.keep = keep
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self) -> None:
        conn, _ = self.listener.accept()
        got = 0
        with conn:
            while got < self.keep:
                data = conn.recv(4096)
                if not data:
                    break
                got += len(data)
        self.listener.close()


async def _feed(tmp_path: Path, keep: int, cancel_at: int | None) -> MachineStatus:
    line = _Line(keep)
    config = parse_config(_config(tmp_path, f"socket://127.0.0.1:{line.port}"), base=tmp_path)
    connector = connector_for(config.machines[0])
    await connector.connect()
    try:

        def progress(at: int, lines: int, nbytes: int, total: int) -> None:
            if cancel_at is not None and at >= cancel_at:
                raise JobCancelled(f"cancelled at line {at}")

        with pytest.raises(DncError):
            await connector.dripfeed("O03000.nc", PROGRAM, 1, progress)
        return await connector.status()
    finally:
        await connector.close()
        line.thread.join(10)


def test_a_broken_drip_feed_is_an_alarm_with_its_text(tmp_path: Path) -> None:
    status = asyncio.run(_feed(tmp_path, keep=2000, cancel_at=None))
    assert classify(status, online=True) is State.ALARM
    (text,) = status.errors
    assert text.startswith("Drip-feed of O03000.nc broke at line "), text
    assert status.program == "O03000.nc"


def test_a_cancelled_drip_feed_is_a_stopped_program(tmp_path: Path) -> None:
    status = asyncio.run(_feed(tmp_path, keep=10**9, cancel_at=50))
    assert classify(status, online=True) is State.STOPPED
    assert status.errors == ()
    assert status.message.startswith("drip-feed of O03000.nc cancelled at line "), status.message
