"""A control's program error is an alarm with its text, not an amber "stopped" with none.

A virtual TNC 640 runs a program whose TOOL CALL names a tool its table does not know: the
control stops the program with an NC error (LSV2 program state "error"). A TNC 640 does not
answer the error list's run information (an iTNC 530 does), so the program state is all the
server can read: the connector's status carries an error text, the one classifier says
alarm, the status timeline stores the text, and utilization counts it as an alarm."""

from __future__ import annotations

import asyncio
import tempfile
import time
from datetime import UTC, datetime, timedelta
from pathlib import Path

from opendnc.server.config.shop import parse_config
from opendnc.server.core.shifts import parse_calendar
from opendnc.server.core.state import State, classify
from opendnc.server.core.status import MachineStatus
from opendnc.server.kinds.lsv2.connector import PROGRAM_ERROR
from opendnc.server.kinds.registry import connector_for
from opendnc.server.machines.timeline import Timeline
from opendnc.server.utilization.sums import Group, Point, summarize
from opendnc.sim.tnc.population import klartext_demo
from opendnc.sim.tnc.server import serve_tnc

AUTOMATIC_KEY = 0x01C3


async def _statuses(profile: str, root: Path) -> tuple[MachineStatus, MachineStatus]:
    """The status before the error, and the first one that says it (within a deadline)."""
    tnc = await serve_tnc(profile, root, port=0)
    try:
        text = f'[[machines]]\nname = "t"\nkind = "lsv2"\nhost = "127.0.0.1"\nport = {tnc.port}\n'
        connector = connector_for(parse_config(text, base=root).machines[0])
        await connector.connect()
        try:
            machine = tnc.control.machine
            machine.tool_known = lambda n: n != 3  # POCKET calls tool 3
            machine.clear_errors()  # (an iTNC 530 starts with the power-on relay message)
            before = await connector.status()
            machine.select("TNC:\\nc_prog\\POCKET.H", klartext_demo("POCKET"))
            machine.press_key(AUTOMATIC_KEY)
            machine.start()
            deadline = time.monotonic() + 30
            while True:
                status = await connector.status()
                if status.errors or time.monotonic() > deadline:
                    return before, status
                await asyncio.sleep(0.05)
        finally:
            await connector.close()
    finally:
        await tnc.close()


def test_a_tnc_640_program_stopped_by_an_nc_error_is_an_alarm_with_text() -> None:
    with tempfile.TemporaryDirectory() as root:
        before, status = asyncio.run(_statuses("tnc640", Path(root)))
    assert classify(before, online=True) is State.READY
    assert status.errors == (PROGRAM_ERROR,)
    assert classify(status, online=True) is State.ALARM
    # the timeline stores it as an alarm with its text, and utilization counts the alarm
    timeline = Timeline(None)
    assert timeline.note("t", status, online=True)
    recorded = timeline.changes["t"][-1]
    assert (recorded.state, recorded.alarm) == (State.ALARM, PROGRAM_ERROR)
    t0 = datetime(2026, 1, 5, 8, tzinfo=UTC)
    points = [
        Point(t0, State.RUNNING),
        Point(t0 + timedelta(minutes=10), State.ALARM, alarm=PROGRAM_ERROR),
    ]
    calendar = parse_calendar({})
    _periods, report = summarize(
        "t",
        points,
        calendar,
        Group.DAY,
        t0,
        t0 + timedelta(hours=1),
        now=t0 + timedelta(minutes=30),
    )
    assert [(a.text, a.count, a.seconds) for a in report.alarms] == [(PROGRAM_ERROR, 1, 1200.0)]


def test_an_itnc_530_says_its_own_error_text() -> None:
    with tempfile.TemporaryDirectory() as root:
        _before, status = asyncio.run(_statuses("itnc530", Path(root)))
    assert status.errors == ("Tool 3 not defined",)
    assert classify(status, online=True) is State.ALARM
