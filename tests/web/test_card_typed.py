"""The card is made from the typed status and state (``render.Seen``), not re-read from the
API's JSON: each field below is what the card's rules say, written out by hand."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta
from pathlib import Path
from zoneinfo import ZoneInfo

import pytest

from tests.peers import require_module

require_module("jinja2")

from opendnc.server.config.shop import parse_config  # noqa: E402
from opendnc.server.core.jobwords import JobKind  # noqa: E402
from opendnc.server.core.state import State  # noqa: E402
from opendnc.server.core.status import MachineStatus  # noqa: E402
from opendnc.server.machines.state import MachineState  # noqa: E402
from opendnc.server.web import render  # noqa: E402

BERLIN = ZoneInfo("Europe/Berlin")
AT = datetime(2026, 3, 2, 13, 2, 31, tzinfo=UTC)  # 14:02:31 CET
NOW = AT + timedelta(seconds=20)


def _seen(
    status: MachineStatus | None, state: State, online: bool = True, **more: object
) -> render.Seen:
    return render.Seen("vf2", "haas_ngc", status, state, online, **more)  # type: ignore[arg-type]


def test_a_running_machine_shows_its_program_line_and_what_the_control_reports() -> None:
    status = MachineStatus(
        AT,
        True,
        execution="ACTIVE",
        mode="MANUAL_DATA_INPUT",
        native_mode="MDI",
        program="O01000",
        line=42,
        part_count=5,
        tool=12,
        overrides={"feed": 99.6},
    )
    c = render.card(_seen(status, State.RUNNING), zone=BERLIN, now=NOW)
    assert c.state is State.RUNNING
    assert c.mode == "manual data input"  # the MTConnect word, for people
    assert c.native_mode == "MDI"
    assert c.execution == ""  # "running (active)" says nothing the state does not
    assert (c.program, c.line) == ("O01000", 42)
    assert (c.parts, c.tool) == (5, 12)
    assert c.overrides == "feed 100\u00a0%"  # rounded, a no-break space before the sign
    assert (c.updated, c.updated_iso) == ("14:02 CET", "2026-03-02T14:02:00+01:00")
    assert (c.job_id, c.percent, c.alarm) == (None, None, "")


@pytest.mark.parametrize(
    ("state", "execution", "said"),
    [
        (State.STOPPED, "FEED_HOLD", "feed hold"),
        (State.STOPPED, "PROGRAM_STOPPED", ""),
        (State.READY, "PROGRAM_COMPLETED", "program completed"),
        (State.READY, "WAIT", ""),
        (State.ALARM, "STOPPED", ""),  # an alarm is said by its text
        (State.UNKNOWN, "UNAVAILABLE", ""),
    ],
)
def test_the_execution_word_is_shown_only_where_it_adds_to_the_state(
    state: State, execution: str, said: str
) -> None:
    c = render.card(_seen(MachineStatus(AT, True, execution=execution), state), now=NOW)
    assert c.execution == said


def test_an_offline_machine_shows_nothing_the_control_said_but_its_alarm_and_printed_line() -> None:
    status = MachineStatus(
        AT,
        False,
        execution="ACTIVE",
        mode="AUTOMATIC",
        program="O7",
        line=3,
        part_count=9,
        errors=("1010 LOW AIR", "2 DOOR"),
        dprnt="X1.0",
        dprnt_at=AT,
    )
    c = render.card(_seen(status, State.OFFLINE, online=False), zone=BERLIN, now=NOW)
    assert (c.mode, c.execution, c.program, c.line, c.parts) == ("", "", "", 0, None)
    assert c.alarm == "1010 LOW AIR; 2 DOOR"
    assert (c.dprnt, c.dprnt_at) == ("X1.0", "2026-03-02 14:02:31 CET")


def test_a_control_that_does_not_answer_reports_no_counter_tool_or_override() -> None:
    status = MachineStatus(AT, False, part_count=5, tool=3, overrides={"feed": 100.0})
    c = render.card(_seen(status, State.UNKNOWN), now=NOW)
    assert (c.parts, c.tool, c.overrides) == (None, None, "")
    # and a tool 0 is an empty spindle, not tool 0
    c = render.card(_seen(MachineStatus(AT, True, tool=0), State.READY), now=NOW)
    assert c.tool is None


def test_a_job_under_way_shows_its_share_and_pace_without_changing_the_state() -> None:
    started = NOW - timedelta(seconds=10)
    job = render.RunningJob(4, "send O1000.nc v2", 2_500, 10_000, started)
    status = MachineStatus(AT, True, execution="READY")
    c = render.card(_seen(status, State.READY, job=job), queued=3, now=NOW)
    assert c.state is State.READY  # a load into memory runs nothing
    assert (c.job_id, c.job_label, c.done, c.total, c.queued) == (
        4,
        "send O1000.nc v2",
        2500,
        10000,
        3,
    )
    assert c.percent == 25  # 2 500 of 10 000 bytes
    assert c.rate == "250 B/s"  # 2 500 bytes in 10 s
    assert c.left == "about 30 s left"  # 7 500 bytes more at that rate
    assert (c.feed_line, c.feed_lines) == (None, None)  # a load, not a drip-feed


def test_a_machine_state_becomes_the_card_through_the_one_classifier(tmp_path: Path) -> None:
    text = '[[machines]]\nname = "vf2"\nkind = "haas_ngc"\nhost = "127.0.0.1"\nmdc_port = 5051\n'
    machine = MachineState(parse_config(text, base=tmp_path).machines[0])
    machine.online = True
    machine.set_status(MachineStatus(AT, True, execution="READY", program="O1"))
    # a drip-feed runs the program it feeds: the machine is running, whatever was polled
    machine.start_job(9, 4_000, kind=JobKind.DRIPFEED, program="O2")
    machine.job_progress, machine.job_line = (1_000, 4_000), (10, 40)
    seen = render.Seen.of(machine, "dripfeed O2 v1")
    assert (seen.name, seen.kind, seen.state) == ("vf2", "haas_ngc", State.RUNNING)
    c = render.card(seen, now=NOW)
    assert (c.state, c.program, c.execution) == (State.RUNNING, "O2", "")
    assert (c.job_id, c.job_label, c.percent) == (9, "dripfeed O2 v1", 25)
    assert (c.feed_line, c.feed_lines) == (10, 40)
    machine.online = False  # the link broke: offline, the job's progress still told
    c = render.card(render.Seen.of(machine), now=NOW)
    assert (c.state, c.program, c.percent) == (State.OFFLINE, "", 25)
