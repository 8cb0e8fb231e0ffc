"""The ``opcua`` kind against the virtual OPC UA server over real loopback sockets: a scripted
run appears on the floor (``/api/machines``) with the script's states, part count and alarm
text within a second, over an unsecured and a Basic256Sha256 session; a server restart
re-subscribes without counting a part twice (docs/opcua-input.md).

asyncua builds a server's address space in seconds, so one server serves the module and one
test drives it (xdist would build a server per worker)."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from cryptography.x509.oid import ExtendedKeyUsageOID

from opendnc.opcua.model import ChannelMode, ChannelState, MachineOperationMode
from opendnc.server.core.state import State, classify
from opendnc.server.kinds.opcua.connector import (
    OpcuaConnector,
    Readings,
    machine_status,
)
from tests.server.harness import wait_for
from tests.server.mtconnect_support import Floor, floor
from tests.server.opcua_support import ServerThread, Step, self_signed, server_thread

LAG_S = 1.0  # the most a change at the control may take to show on the floor
POLL_S = 0.2  # the machines' poll_interval: the floor's lag is about this plus a publish


@pytest.fixture(scope="module")
def certs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("pki")
    server_cert, server_key = self_signed(
        folder, "server", "urn:opendnc:sim:opcua", ExtendedKeyUsageOID.SERVER_AUTH
    )
    client_cert, client_key = self_signed(
        folder, "client", "urn:opendnc:client", ExtendedKeyUsageOID.CLIENT_AUTH
    )
    return {"server_cert": server_cert, "server_key": server_key,
            "client_cert": client_cert, "client_key": client_key}  # fmt: skip


@pytest.fixture(scope="module")
def opcua(certs: dict[str, Path]) -> Iterator[ServerThread]:
    with server_thread(
        ["mill", "secure", "vmc"],
        certificate=certs["server_cert"],
        private_key=certs["server_key"],
    ) as server:
        yield server


def _machine(server: ServerThread, name: str, **extra: object) -> dict[str, object]:
    return {
        "name": name,
        "kind": "opcua",
        "endpoint": server.server.url,
        "machine": name,
        "poll_interval": POLL_S,
        **extra,
    }


# The script, and what the floor must show after each step: the classifier's state, the
# execution word our mapping gives, and what the script put there (program, parts, alarm).
SCRIPT: list[tuple[str, Step, dict[str, Any]]] = [
    ("start", lambda m: m.start("O1234"), {"state": "running", "execution": "ACTIVE"}),
    ("cut", lambda m: m.cut(85.0), {"program": "O1234", "overrides": {"feed": 85.0}}),
    ("feed hold", lambda m: m.feed_hold(), {"state": "stopped", "execution": "INTERRUPTED"}),
    ("resume", lambda m: m.resume(), {"state": "running", "execution": "ACTIVE"}),
    (
        "alarm",
        lambda m: m.alarm("1010", "SPINDLE OVERLOAD"),
        {"state": "alarm", "errors": ["1010 SPINDLE OVERLOAD"], "part_count": 3},
    ),
    ("reset", lambda m: m.reset(), {"state": "ready", "execution": "READY", "errors": []}),
    ("start again", lambda m: m.start("O1234"), {"state": "running", "part_count": 3}),
    (
        "part counted",
        lambda m: m.finish(),
        {"state": "ready", "execution": "PROGRAM_COMPLETED", "part_count": 4},
    ),
]  # fmt: skip


def _shows(want: dict[str, Any]) -> Callable[[dict[str, Any]], bool]:
    def check(machine: dict[str, Any]) -> bool:
        status = machine["status"] or {}
        seen = {"state": machine["state"], **status}
        return all(seen.get(key) == value for key, value in want.items())

    return check


def _connector(shop: Floor, name: str) -> OpcuaConnector:
    connector = shop.connectors[name][-1]
    assert isinstance(connector, OpcuaConnector)
    return connector


def test_a_scripted_run_shows_within_a_second_and_a_restart_resubscribes(
    tmp_path: Path, opcua: ServerThread, certs: dict[str, Path]
) -> None:
    # The same script on two machines of the server: one read over an unsecured session, one
    # over Basic256Sha256 SignAndEncrypt with the self-signed certificate made above. (One
    # test: the server takes seconds to build, and xdist would build one per worker.)
    secure = _machine(
        opcua,
        "secure",
        security_policy="Basic256Sha256",
        security_mode="SignAndEncrypt",
        certificate=str(certs["client_cert"]),
        private_key=str(certs["client_key"]),
    )
    names = ["mill", "secure"]
    # Powered on before the DNC server starts: it first sees 3 parts made (a server that
    # connects fast enough to see the count go 0 -> 3 counts those 3 as made while it watched).
    for name in names:
        opcua.step(name, lambda m: m.power_on(parts=3))
    with floor(tmp_path, [_machine(opcua, "mill"), secure]) as shop:
        for name in names:
            shop.until(name, "ready", _shows({"state": "ready", "part_count": 3}), 0)
        lags: dict[str, list[float]] = {name: [] for name in names}
        for what, action, want in SCRIPT:
            done = {name: opcua.step(name, action) for name in names}
            seen = shop.until_each(what, dict.fromkeys(names, _shows(want)), done)
            for name, lag in seen.items():
                lags[name].append(lag)
            if what == "alarm":
                page = shop.page("/")
                card = page[page.index('data-machine="secure"') :]
                card = card[: card.index("</dl>")]
                assert "OPC UA (umati)" in card
                assert "Alarm: 1010 SPINDLE OVERLOAD" in card
        steps = [s[0] for s in SCRIPT]
        for name in names:
            assert max(lags[name]) < LAG_S, (name, dict(zip(steps, lags[name], strict=True)))
        plain, encrypted = _connector(shop, "mill"), _connector(shop, "secure")
        assert plain.sessions == encrypted.sessions == 1
        assert encrypted.security_policy_uri.endswith("#Basic256Sha256")
        assert plain.security_policy_uri.endswith("#None")
        # subscribed, not polled: each step came as a notification (data changes and events)
        assert plain.readings.notifications >= len(SCRIPT)
        # the stacklight followed the script: nothing lit after the part was counted
        assert plain.readings.lights
        assert not any(light.on for light in plain.readings.lights.values())

        # The server restarts: every session is lost, each supervisor connects again, browses
        # and subscribes anew; the values come back, and the next part counts once.
        errors = {name: shop.machine(name)["link_errors"] for name in names}
        opcua.step("mill", lambda m: m.start("O2000"))
        opcua.run(opcua.server.restart)
        for name in names:
            wait_for("a new session", lambda n=name: _connector(shop, n).sessions == 2, timeout=10)
            assert shop.machine(name)["link_errors"] > errors[name]  # it went offline
        shop.until("mill", "back", _shows({"state": "running", "program": "O2000"}), 0)
        shop.until("secure", "back", _shows({"state": "ready", "part_count": 4}), 0)
        done = opcua.step("mill", lambda m: m.finish())
        lag = shop.until("mill", "one part more", _shows({"part_count": 5}), done)
        assert lag < LAG_S

        # Utilization counts the two parts made while the server watched (3 -> 4 -> 5), not
        # the count the new session reported again.
        def parts() -> Any:
            report = shop.api("/api/utilization", machines="mill")
            return report["machines"][0]["totals"]["parts"]

        wait_for("the parts counted", lambda: parts() == 2, timeout=5, describe=parts)


@pytest.mark.parametrize(
    ("readings", "state", "execution", "mode"),
    [
        (Readings(channel_state=ChannelState.ACTIVE), State.RUNNING, "ACTIVE", ""),
        (Readings(channel_state=ChannelState.INTERRUPTED), State.STOPPED, "INTERRUPTED", ""),
        (Readings(channel_state=ChannelState.RESET), State.READY, "READY", ""),
        (
            Readings(channel_state=ChannelState.RESET, program_state="Ended"),
            State.READY,
            "PROGRAM_COMPLETED",
            "",
        ),
        # no channel: the program's state alone
        (Readings(program_state="Running"), State.RUNNING, "ACTIVE", ""),
        (Readings(program_state="Aborted"), State.STOPPED, "STOPPED", ""),
        # a server that says nothing of either is not guessed at
        (Readings(), State.UNKNOWN, "UNAVAILABLE", ""),
        (
            Readings(channel_state=ChannelState.ACTIVE, alarms={"7": "7 DOOR OPEN"}),
            State.ALARM,
            "ACTIVE",
            "",
        ),
        (
            Readings(channel_state=0, channel_mode=ChannelMode.MDA_MDI),
            State.RUNNING,
            "ACTIVE",
            "MANUAL_DATA_INPUT",
        ),
        (
            Readings(channel_mode=ChannelMode.JOG_INCREMENT, operation_mode=1),
            State.UNKNOWN,
            "UNAVAILABLE",
            "MANUAL",
        ),
        (Readings(operation_mode=1), State.UNKNOWN, "UNAVAILABLE", "AUTOMATIC"),
    ],
)  # fmt: skip
def test_the_model_maps_to_our_status(
    readings: Readings, state: State, execution: str, mode: str
) -> None:
    status = machine_status(readings)
    assert classify(status, online=True) is state
    assert status.execution == execution
    assert status.mode == mode


def test_a_mode_without_our_word_keeps_its_own() -> None:
    status = machine_status(Readings(channel_mode=ChannelMode.REFERENCE))
    assert (status.mode, status.native_mode) == ("", "REFERENCE")
    status = machine_status(Readings(operation_mode=MachineOperationMode.SETUP))
    assert (status.mode, status.native_mode) == ("", "SETUP")
