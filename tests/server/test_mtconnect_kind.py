"""The ``mtconnect`` kind against the virtual agent over real sockets: a scripted run appears on
the floor (``/api/machines``) with the script's states, part count and alarm text within a
second; an agent restart and a sequence gap lose and double nothing
(docs/mtconnect-input.md)."""

from __future__ import annotations

import statistics
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from opendnc.mtconnect.device_state import Snapshot
from opendnc.server.core.events import MachineStatusChanged
from opendnc.server.core.state import State, classify
from opendnc.server.kinds.mtconnect.connector import (
    EMERGENCY_STOP,
    MtconnectConnector,
    agent_status,
)
from opendnc.server.outputs.items import items_of
from opendnc.sim.mtconnect.machine import ScriptedMachine
from tests.server.harness import wait_for
from tests.server.mtconnect_support import AgentThread, Floor, agent_thread, floor

# A change at the agent shows on the floor in about POLL_S plus the stream's delay: 0.15-0.22 s
# a step on a quiet machine, which the median below holds to the issue's second. One step of a
# loaded CI run took 1.8 s (load 12-20 on 2 cores): the longest step is held to a bound a lost
# or polled-late change would pass, not to a speed (benchmarks/fleet.py measures the ages).
LAG_S = 1.0  # the median step
LONGEST_S = 5.0  # any step
POLL_S = 0.2  # the machines' poll_interval here: the floor's lag is about this plus the stream's


def _machine(agent: AgentThread, name: str, **extra: object) -> dict[str, object]:
    return {
        "name": name,
        "kind": "mtconnect",
        "url": agent.agent.url,
        "device": name,
        "poll_interval": POLL_S,
        **extra,
    }


Step = tuple[str, Callable[[ScriptedMachine], object], dict[str, Any]]

# The script, and what the floor must show after each step: the classifier's state, the
# agent's execution word, and what the script put there (program, line, parts, alarm text).
SCRIPT: list[Step] = [
    ("start", lambda m: m.start("O1234"), {"state": "running", "execution": "ACTIVE"}),
    ("cut", lambda m: m.cut(25), {"state": "running", "line": 26, "program": "O1234"}),
    ("feed hold", lambda m: m.feed_hold(), {"state": "stopped", "execution": "FEED_HOLD"}),
    ("resume", lambda m: m.resume(), {"state": "running", "execution": "ACTIVE"}),
    (
        "alarm",
        lambda m: m.alarm("1010", "SPINDLE OVERLOAD"),
        {"state": "alarm", "execution": "STOPPED", "errors": ["1010 SPINDLE OVERLOAD"]},
    ),
    ("reset", lambda m: m.reset(), {"state": "ready", "execution": "READY", "errors": []}),
    ("start again", lambda m: m.start("O1234"), {"state": "running", "part_count": 3}),
    (
        "part counted",
        lambda m: m.finish(),
        {"state": "ready", "execution": "PROGRAM_COMPLETED", "part_count": 4},
    ),
    ("e-stop", lambda m: m.emergency_stop(), {"state": "alarm", "errors": [EMERGENCY_STOP]}),
    ("reset e-stop", lambda m: m.reset(), {"state": "ready", "errors": []}),
    ("switched off", lambda m: m.power_off(), {"state": "offline"}),
]


def _shows(want: dict[str, Any]) -> Callable[[dict[str, Any]], bool]:
    def check(machine: dict[str, Any]) -> bool:
        status = machine["status"] or {}
        seen = {"state": machine["state"], **status}
        return all(seen.get(key) == value for key, value in want.items())

    return check


def test_a_scripted_run_shows_on_the_floor_within_a_second(tmp_path: Path) -> None:
    # The same script on two agents: one streams ("mill"), one does not and is polled with
    # current ("old"); both machines on one floor.
    with (
        agent_thread(["mill"]) as agent,
        agent_thread(["old"], streaming=False) as polled,
        floor(tmp_path, [_machine(agent, "mill"), _machine(polled, "old")]) as shop,
    ):
        machines = {"mill": agent, "old": polled}
        for name, sim in machines.items():
            sim.step(name, lambda m: m.power_on(parts=3))
            shop.until(name, "ready", _shows({"state": "ready", "part_count": 3}), 0)
        lags: dict[str, list[float]] = {"mill": [], "old": []}
        for what, action, want in SCRIPT:
            done = {name: sim.step(name, action) for name, sim in machines.items()}
            seen = shop.until_each(what, dict.fromkeys(machines, _shows(want)), done)
            for name, lag in seen.items():
                lags[name].append(lag)
            if what == "alarm":
                # the card, as the dashboard renders it: the kind, the alarm's text, the parts
                page = shop.page("/")
                card = page[page.index('data-machine="mill"') :]
                card = card[: card.index("</dl>")]
                assert "MTConnect agent" in card
                assert "Alarm: 1010 SPINDLE OVERLOAD" in card
                assert '<dd class="parts">3</dd>' in card
                # and the machine's own page, without the file browser an agent has not
                page = shop.page("/machines/mill")
                assert "MTConnect agent" in page
                assert "1010 SPINDLE OVERLOAD" in page
                assert "Files on the control" not in page
        steps = [s[0] for s in SCRIPT]
        for name in machines:
            said = (name, dict(zip(steps, lags[name], strict=True)))
            assert statistics.median(lags[name]) < LAG_S, said
            assert max(lags[name]) < LONGEST_S, said
        streamed, old = _connector(shop, "mill").reader, _connector(shop, "old").reader
        assert streamed is not None
        assert old is not None
        assert streamed.streaming
        assert streamed.counts.documents > len(SCRIPT)
        assert not old.streaming  # refused UNSUPPORTED: it polls current
        assert old.counts.streams == 0


def _connector(shop: Floor, name: str) -> MtconnectConnector:
    connector = shop.connectors[name][-1]
    assert isinstance(connector, MtconnectConnector)
    return connector


def test_an_agent_restart_and_a_sequence_gap_lose_and_double_nothing(tmp_path: Path) -> None:
    with (
        agent_thread(["vmc"], buffer_size=16) as agent,
        floor(tmp_path, [_machine(agent, "vmc")]) as shop,
    ):
        agent.step("vmc", lambda m: m.power_on(parts=10))
        agent.step("vmc", lambda m: m.start("O2000"))
        shop.until("vmc", "running", _shows({"state": "running", "part_count": 10}), 0)
        first = agent.call(lambda: agent.agent.instance)
        agent.run(agent.agent.restart)
        assert agent.call(lambda: agent.agent.instance) != first
        # the agent resends every value after its restart: none of them counts again
        done = agent.step("vmc", lambda m: m.finish())
        shop.until("vmc", "one part more", _shows({"part_count": 11}), done)
        # the reader asked the agent again while it restarted: the machine never went offline
        assert shop.machine("vmc")["link_errors"] == 0
        # the link follows the new instance (probed again, by the reader or a reconnect)
        reader = _connector(shop, "vmc").reader
        assert reader is not None
        assert reader.state is not None
        assert reader.state.instance_id == agent.call(lambda: agent.agent.instance)

        # A buffer of 16 observations, and a link that stalls while 30 parts are made: the
        # stream resumes from a sequence that has left the buffer (OUT_OF_RANGE), and the
        # reader reads current instead of the lost observations.
        gaps = reader.counts.gaps
        agent.call(lambda: setattr(agent.agent, "stalled", True))
        for _ in range(30):
            agent.step("vmc", lambda m: (m.start("O3000"), m.finish()))
        done = agent.step("vmc", lambda m: m.alarm("77", "COOLANT LOW"))
        agent.call(lambda: setattr(agent.agent, "stalled", False))
        want = {"part_count": 41, "state": "alarm", "errors": ["77 COOLANT LOW"]}
        shop.until("vmc", "after the gap", _shows(want), done)
        assert _connector(shop, "vmc").reader is reader  # no reconnect: the reader resynced
        assert reader.counts.gaps == gaps + 1

        # Utilization counts the parts made while the server watched: 1 before the gap and 30
        # in it, none again for the restart's resent count (the recorder writes within 1 s).
        def parts() -> Any:
            report = shop.api("/api/utilization", machines="vmc")
            return report["machines"][0]["totals"]["parts"]

        wait_for("the parts counted", lambda: parts() == 31, timeout=5, describe=parts)


@pytest.mark.parametrize(
    ("snapshot", "state", "execution"),
    [
        (Snapshot(availability="AVAILABLE", execution="ACTIVE"), State.RUNNING, "ACTIVE"),
        (Snapshot(availability="AVAILABLE", execution="WAIT"), State.READY, "WAIT"),
        (Snapshot(availability="AVAILABLE", execution="INTERRUPTED"), State.STOPPED, "INTERRUPTED"),
        # the later standard's word for an M01 stop is our model's OPTIONAL_STOP
        (
            Snapshot(availability="AVAILABLE", execution="PROGRAM_OPTIONAL_STOP"),
            State.STOPPED,
            "OPTIONAL_STOP",
        ),
        # a word outside the standard is not guessed at
        (Snapshot(availability="AVAILABLE", execution="RUNNING"), State.UNKNOWN, "UNAVAILABLE"),
        (Snapshot(availability="AVAILABLE"), State.UNKNOWN, "UNAVAILABLE"),
        (Snapshot(availability=None, execution="ACTIVE"), State.OFFLINE, "ACTIVE"),
        (
            Snapshot(availability="AVAILABLE", execution="ACTIVE", emergency_stop="TRIGGERED"),
            State.ALARM,
            "ACTIVE",
        ),
        (
            Snapshot(availability="AVAILABLE", execution="READY", faults=("1 X",)),
            State.ALARM,
            "READY",
        ),
        (
            Snapshot(availability="AVAILABLE", execution="READY", warnings=("9 LOW OIL",)),
            State.READY,
            "READY",
        ),
    ],
)
def test_the_agents_words_go_through_the_one_classifier(
    snapshot: Snapshot, state: State, execution: str
) -> None:
    status = agent_status(snapshot)
    assert status.execution == execution
    assert classify(status, online=True) is state
    assert ("UNAVAILABLE" in status.message) == (state is State.OFFLINE)


def test_the_mode_is_mtconnects_and_a_foreign_word_is_kept_apart() -> None:
    ours = agent_status(Snapshot(availability="AVAILABLE", controller_mode="MANUAL_DATA_INPUT"))
    assert (ours.mode, ours.native_mode) == ("MANUAL_DATA_INPUT", "")
    theirs = agent_status(Snapshot(availability="AVAILABLE", controller_mode="FEED_HOLD"))
    assert (theirs.mode, theirs.native_mode) == ("", "FEED_HOLD")


def test_the_open_outputs_take_an_agents_machine_as_any_other() -> None:
    # MQTT, Sparkplug B and our SHDR adapter all read items_of(): the same items, the alarm's
    # text in the SYSTEM condition
    snapshot = Snapshot(
        availability="AVAILABLE",
        execution="STOPPED",
        controller_mode="AUTOMATIC",
        program="O1234",
        line=26,
        part_count=4,
        faults=("1010 SPINDLE OVERLOAD",),
    )
    items = items_of(MachineStatusChanged("mill", True, agent_status(snapshot)))
    assert items["availability"] == "AVAILABLE"
    assert (items["execution"], items["controller_mode"]) == ("STOPPED", "AUTOMATIC")
    assert (items["program"], items["line_number"], items["part_count"]) == ("O1234", 26, 4)
    assert items["system"] == ("1010 SPINDLE OVERLOAD",)
