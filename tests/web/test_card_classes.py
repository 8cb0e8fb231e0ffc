"""Every consumer of a machine's status reads its state from the one classifier: the card's
word and andon colour class, the MTConnect and MQTT items' availability, the timeline."""

from __future__ import annotations

from datetime import UTC, datetime
from pathlib import Path

import pytest

from tests.peers import require_module

require_module("jinja2")

from opendnc.server.config.shop import parse_config  # noqa: E402
from opendnc.server.core.status import MachineStatus  # noqa: E402
from opendnc.server.machines.state import MachineState  # noqa: E402
from opendnc.server.machines.timeline import Timeline  # noqa: E402
from opendnc.server.outputs.items import items_of  # noqa: E402
from opendnc.server.web import render  # noqa: E402

AT = datetime(2026, 3, 2, 7, 0, tzinfo=UTC)


def _machine(tmp_path: Path) -> MachineState:
    text = '[[machines]]\nname = "vf2"\nkind = "haas_ngc"\nhost = "127.0.0.1"\nmdc_port = 5051\n'
    return MachineState(parse_config(text, base=tmp_path).machines[0])


@pytest.mark.parametrize(
    ("online", "status", "state", "available"),
    [
        (True, MachineStatus(AT, True, execution="ACTIVE"), "running", "AVAILABLE"),
        (True, MachineStatus(AT, True, execution="READY"), "ready", "AVAILABLE"),
        (True, MachineStatus(AT, True, execution="FEED_HOLD"), "stopped", "AVAILABLE"),
        (True, MachineStatus(AT, True, execution="READY", errors=("1010",)), "alarm", "AVAILABLE"),
        (False, MachineStatus(AT, False, message="refused"), "offline", "UNAVAILABLE"),
        (True, MachineStatus(AT, True), "unknown", "AVAILABLE"),  # reachable, says nothing
    ],
)
def test_the_card_the_items_and_the_timeline_agree(
    tmp_path: Path, online: bool, status: MachineStatus, state: str, available: str
) -> None:
    machine = _machine(tmp_path)
    machine.online = online
    machine.set_status(status)
    # a job under way (a load into memory) changes nothing of the machine's state
    machine.job_id, machine.job_progress = 4, (870, 1000)

    card = render.card(render.Seen.of(machine, "send O1000.nc v2"))
    html = render.environment().get_template("_card.html").render(c=card, whole=False)
    assert card.state == state
    assert f'class="card-body state-{state}" data-state="{state}"' in html
    assert f'<p class="pill {state}">' in html
    assert card.percent == 87
    assert " · 87%" in render.queue_progress_oob(card)

    event = machine.event()
    assert event.state.value == state
    assert items_of(event)["availability"] == available

    timeline = Timeline()
    timeline.note("vf2", machine.status, online=machine.online, at=AT)
    assert timeline.history("vf2", AT)[0].state.value == state
