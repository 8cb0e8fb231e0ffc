"""The MTConnect SHDR adapter, read the way an agent reads it.

No MTConnect agent installs here (Debian has none; PyPI's ``mtconnect`` is an agent library
without an SHDR reader), so the peer is a strict SHDR reader written in the test from the
standard's facts (tests/server/outputs_support.py). The server runs as its own process.
"""

from __future__ import annotations

import socket
from collections.abc import Iterator
from datetime import UTC, datetime
from pathlib import Path
from typing import Any
from xml.etree import ElementTree as ET

import pytest
from hypothesis import given
from hypothesis import strategies as st

from opendnc.server.config.shop import ConfigError, parse_config
from opendnc.server.outputs.items import Reading
from opendnc.server.outputs.shdr import (
    MTCONNECT_VERSION,
    condition_lines,
    devices_xml,
    event_line,
    message_line,
    shdr_state,
)
from opendnc.sim.haas.machine import Mode
from tests.peers import require_module, require_reference
from tests.server.harness import Procs, auth, create_key, free_port, httpx, listening, wait_for
from tests.server.outputs_support import ShdrReader, start_outputs_server
from tests.server.test_from_the_control import FleetThread

KEYS = {
    "availability", "execution", "controller_mode", "program", "line_number", "part_count",
    "tool_number", "feed_override", "rapid_override", "spindle_override", "message",
}  # fmt: skip


@pytest.fixture
def shop(tmp_path: Path) -> Iterator[FleetThread]:
    fleet = FleetThread(tmp_path / "machines", tnc=1, haas=1)
    try:
        yield fleet
    finally:
        fleet.stop()


def test_each_machine_is_a_device_on_its_own_port(
    tmp_path: Path, shop: FleetThread, procs: Procs
) -> None:
    ports = {"tnc-1": free_port(), "haas-1": free_port(), "away": free_port()}
    extra = (
        "[[machines]]\n"
        'name = "away"\nkind = "haas_ngc"\nhost = "127.0.0.1"\n'
        f"mdc_port = {free_port()}\npoll_interval = 0.2\n\n"
        '[mtconnect]\nbind = "127.0.0.1:0"\n'
        f'ports = {{ "tnc-1" = {ports["tnc-1"]}, "haas-1" = {ports["haas-1"]}, '
        f'"away" = {ports["away"]} }}\n'
    )
    http = start_outputs_server(tmp_path, procs, shop.fleet, extra)
    for port in ports.values():
        wait_for("the SHDR port", listening(port), describe=lambda: procs.log("server"))

    haas = ShdrReader(ports["haas-1"])
    try:
        # The whole state comes first, every key, then what the control says.
        haas.until("every item", lambda: haas.values.keys() >= KEYS and "system" in haas.conditions)
        haas.until("available", lambda: haas.values["availability"] == "AVAILABLE")
        assert haas.values["controller_mode"] == "MANUAL_DATA_INPUT"  # a Haas in MDI
        assert haas.conditions["system"] == {"": "NORMAL"}
        haas.send("* PING")
        pong = haas.until("the pong", lambda: haas.pongs)
        assert pong[0] > 0

        # The mode switch to MEM: only the change follows.
        seen = len(haas.lines)
        sim = shop.fleet.sims["haas-1"]
        shop.call(lambda: sim.control.set_mode(Mode.MEM))
        haas.until("the mode change", lambda: haas.values["controller_mode"] == "AUTOMATIC")
        after = haas.lines[seen:]
        assert all("|controller_mode|" in line for line in after if "|" in line), after
    finally:
        haas.close()

    # A second agent (or the same one reconnecting) gets the whole state again.
    again = ShdrReader(ports["haas-1"])
    try:
        again.until("the state again", lambda: again.values.keys() >= KEYS)
        assert again.values["controller_mode"] == "AUTOMATIC"
    finally:
        again.close()

    tnc = ShdrReader(ports["tnc-1"])
    try:
        tnc.until("the TNC available", lambda: tnc.values.get("availability") == "AVAILABLE")
        assert tnc.values["execution"] != "UNAVAILABLE"
        # The virtual TNC reports its overrides (LSV2 run information) in percent.
        tnc.until(
            "overrides", lambda: tnc.values.get("feed_override", "UNAVAILABLE") != "UNAVAILABLE"
        )
        assert 0 <= float(tnc.values["feed_override"]) <= 150
    finally:
        tnc.close()

    away = ShdrReader(ports["away"])
    try:
        away.until("the unreachable machine's state", lambda: away.values.keys() >= KEYS)
        assert away.values["availability"] == "UNAVAILABLE"
        unknown = {k for k, v in away.values.items() if v == "UNAVAILABLE"}
        assert unknown >= KEYS - {"message"}
        assert away.conditions["system"] == {"": "UNAVAILABLE"}
    finally:
        away.close()

    # The Devices file for an agent names every key the adapter sends, once per device.
    key = create_key(tmp_path / "shop.toml", f"sqlite:///{tmp_path / 'opendnc.db'}", "viewer")
    with httpx.Client(base_url=f"http://127.0.0.1:{http}", timeout=30) as client:
        got = client.get("/api/mtconnect/devices.xml", headers=auth(key))
        outputs = client.get("/api/outputs", headers=auth(key)).json()
    assert outputs["mqtt"] is None
    assert {n: o["port"] for n, o in outputs["mtconnect"].items()} == ports
    assert got.status_code == 200, got.text
    # It is valid by the schema of the version it declares (what an agent checks it against).
    _validate_devices(got.text)
    ns = {"m": f"urn:mtconnect.org:MTConnectDevices:{MTCONNECT_VERSION}"}
    root = ET.fromstring(got.content)
    devices = root.findall(".//m:Device", ns)
    assert [d.get("name") for d in devices] == ["tnc-1", "haas-1", "away"]
    ids = [e.get("id") for e in root.iter() if e.get("id")]
    assert len(ids) == len(set(ids))
    for device in devices:
        names = {d.get("name") for d in device.iter(f"{{{ns['m']}}}DataItem")}
        assert names == KEYS | {"system", "dprnt"}


def _validate_devices(document: str) -> None:
    """Validate a Devices file against the MTConnect schema of the version it declares (the
    Institute's schemas are XSD 1.1, which lxml's libxml2 cannot read: xmlschema can)."""
    root = ET.fromstring(document)
    version = root.find("{*}Header").get("version")  # type: ignore[union-attr]
    assert root.tag == f"{{urn:mtconnect.org:MTConnectDevices:{version}}}MTConnectDevices"
    xsd = require_reference(f"mtconnect-schema/MTConnectDevices_{version}.xsd")
    errors = [str(e).splitlines()[0] for e in _schema(xsd).iter_errors(document)]
    assert errors == []


_SCHEMAS: dict[Path, object] = {}


def _schema(path: Path) -> Any:
    xmlschema = require_module("xmlschema")
    if path not in _SCHEMAS:
        _SCHEMAS[path] = xmlschema.XMLSchema11(str(path))
    return _SCHEMAS[path]


def test_the_devices_file_is_valid_by_the_schema_it_declares() -> None:
    # Names that make ids awkward: digits first, dashes and dots, two that fold alike.
    document = devices_xml(["mill-1", "mill_1", "2lathe", "vf.2", "Ünïcode"], "dnc 1")
    _validate_devices(document)
    header = ET.fromstring(document).find("{*}Header")
    assert header is not None
    assert int(header.get("assetBufferSize", "0")) >= 1  # the schema's least


def test_the_schema_check_catches_what_the_old_file_had_wrong() -> None:
    # The check is real: the file as it was (version 1.3, an asset buffer of 0) fails it.
    old = devices_xml(["mill-1"], "dnc").replace(MTCONNECT_VERSION, "1.3")
    old = old.replace('assetBufferSize="1"', 'assetBufferSize="0"')
    xsd = require_reference("mtconnect-schema/MTConnectDevices_1.3.xsd")
    errors = "\n".join(str(e) for e in _schema(xsd).iter_errors(old))
    assert "assetBufferSize" in errors
    assert "LINE_NUMBER" in errors
    assert "ABSOLUTE" in errors


def test_an_agent_that_stops_reading_does_not_stop_the_others(
    tmp_path: Path, shop: FleetThread, procs: Procs
) -> None:
    port = free_port()
    extra = f'[mtconnect]\nbind = "127.0.0.1:0"\nports = {{ "haas-1" = {port} }}\n'
    start_outputs_server(tmp_path, procs, shop.fleet, extra)
    wait_for("the SHDR port", listening(port), describe=lambda: procs.log("server"))
    silent = socket.create_connection(("127.0.0.1", port), 10)  # connects, never reads
    reader = ShdrReader(port)
    try:
        reader.until("available", lambda: reader.values.get("availability") == "AVAILABLE")
        sim = shop.fleet.sims["haas-1"]
        for mode in (Mode.MEM, Mode.MDI, Mode.MEM):
            shop.call(lambda m=mode: sim.control.set_mode(m))  # type: ignore[misc]
            want = "AUTOMATIC" if mode is Mode.MEM else "MANUAL_DATA_INPUT"
            reader.until(want, lambda w=want: reader.values["controller_mode"] == w)  # type: ignore[misc]
    finally:
        reader.close()
        silent.close()


# -- the line format --------------------------------------------------------------------

T = datetime(2026, 11, 23, 22, 0, 0, 123456, tzinfo=UTC)
TS = "2026-11-23T22:00:00.123456Z"
texts = st.text(st.characters(codec="utf-8", exclude_categories=("Cs",)), max_size=40)


@given(program=texts, message=texts)
def test_any_text_stays_one_line_with_its_fields(program: str, message: str) -> None:
    reader = ShdrReader.__new__(ShdrReader)
    reader.values, reader.conditions, reader.pongs, reader.lines = {}, {}, [], []
    lines = [event_line(TS, [("program", program), ("part_count", 3)])]
    lines.append(message_line(TS, "message", message))
    for line in lines:
        assert "\n" not in line
        reader.apply(line)
    assert reader.values["part_count"] == "3"

    def travelled(text: str) -> str:
        # A field separator becomes '/', line breaks and runs of blanks one space; a blank
        # text is no value at all.
        return " ".join(text.replace("|", "/").split()) or "UNAVAILABLE"

    assert reader.values["message"] == travelled(message)
    assert reader.values["program"] == travelled(program)


@given(
    st.lists(texts.filter(str.strip), max_size=4, unique=True),
    st.lists(texts.filter(str.strip), max_size=4, unique=True),
)
def test_conditions_end_with_what_is_active(before: list[str], now: list[str]) -> None:
    reader = ShdrReader.__new__(ShdrReader)
    reader.values, reader.conditions, reader.pongs, reader.lines = {}, {}, [], []
    for line in condition_lines(TS, "system", tuple(before)) + condition_lines(
        TS, "system", tuple(now), tuple(before)
    ):
        reader.apply(line)
    active = reader.conditions["system"]
    if now:
        assert sorted(active.values()) == ["FAULT"] * len(now)
    else:
        assert active == {"": "NORMAL"}


def test_events_that_changed_together_share_a_line() -> None:
    lines = shdr_state(
        {
            "execution": Reading("ACTIVE", T),
            "program": Reading("O1000", T),
            "message": Reading(None, T),
            "system": Reading((), T),
        }
    )
    assert lines == [
        f"{TS}|execution|ACTIVE|program|O1000",
        f"{TS}|message||UNAVAILABLE",
        f"{TS}|system|NORMAL||||",
    ]


@pytest.mark.parametrize(
    ("toml", "key"),
    [
        ('[mqtt]\nurl = "http://broker"\n', "mqtt.url"),
        ('[mqtt]\nurl = "mqtt://broker"\nprefix = "a/#/b"\n', "mqtt.prefix"),
        ('[mqtt]\nurl = "mqtt://broker"\nprefix = "a//b"\n', "mqtt.prefix"),
        ('[mqtt]\nurl = "mqtt://broker"\npassword = "x"\n', "mqtt.password"),
        ('[mqtt]\nurl = "mqtt://broker"\nca_file = "ca.pem"\n', "mqtt.ca_file"),
        ('[mqtt]\nurl = "mqtt://broker"\nqos = 2\n', "mqtt.qos"),
        ('[mtconnect]\nbind = "7878"\n', "mtconnect.bind"),
        ('[mtconnect]\nports = { "nope" = 7000 }\n', "mtconnect.ports.nope"),
        ('[mtconnect]\nports = { "m1" = 70000 }\n', "mtconnect.ports.m1"),
        ('[mtconnect]\nbind = "127.0.0.1:7000"\nports = { "m2" = 7000 }\n', "mtconnect.ports.m2"),
    ],
)
def test_output_settings_name_the_bad_key(tmp_path: Path, toml: str, key: str) -> None:
    machines = "".join(
        f'[[machines]]\nname = "{n}"\nkind = "haas_ngc"\nhost = "127.0.0.1"\n\n'
        for n in ("m1", "m2")
    )
    with pytest.raises(ConfigError) as err:
        parse_config(machines + toml, base=tmp_path)
    assert err.value.key == key


def test_output_settings_as_documented(tmp_path: Path) -> None:
    machines = "".join(
        f'[[machines]]\nname = "{n}"\nkind = "haas_ngc"\nhost = "127.0.0.1"\n\n'
        for n in ("m1", "m2", "m3")
    )
    text = (
        machines
        + '[mqtt]\nurl = "mqtts://broker.local"\nprefix = "acme/plant1/milling"\n'
        + 'username = "dnc"\npassword = "pw"\n\n'
        + '[mtconnect]\nbind = "0.0.0.0:7878"\nports = { "m3" = 7900 }\n'
    )
    config = parse_config(text, base=tmp_path)
    assert config.mqtt is not None
    assert config.mtconnect is not None
    assert (config.mqtt.host, config.mqtt.port, config.mqtt.tls) == ("broker.local", 8883, True)
    assert config.mtconnect.ports == {"m1": 7878, "m2": 7879, "m3": 7900}


def test_a_taken_port_is_an_error_naming_the_machine(tmp_path: Path, procs: Procs) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        config = tmp_path / "shop.toml"
        config.write_text(
            f'[server]\nbind = "127.0.0.1:{free_port()}"\n\n'
            '[[machines]]\nname = "mill-1"\nkind = "haas_ngc"\nhost = "127.0.0.1"\n\n'
            f'[mtconnect]\nbind = "127.0.0.1:{port}"\n'
        )
        proc = procs.start("server", "serve", "--config", str(config))
        assert proc.wait(60) == 1
    log = procs.log("server")
    assert f"mtconnect: mill-1: cannot listen on 127.0.0.1:{port}" in log, log
    assert "Traceback" not in log


def test_the_readme_configuration_is_valid_and_says_the_right_ports(tmp_path: Path) -> None:
    readme = (Path(__file__).resolve().parents[2] / "README.md").read_text("utf-8")
    block = readme.split("```text\n[server]\n", 1)[1].split("```", 1)[0]
    config = parse_config("[server]\n" + block, base=tmp_path)
    assert config.mqtt is not None
    assert config.mtconnect is not None
    # The comment on bind names each machine's port; the configuration must agree.
    comment = next(line for line in block.splitlines() if line.startswith('bind = "0.0.0.0:7878"'))
    said = dict(
        (name, int(port))
        for name, port in (part.split(" on ") for part in comment.split("#")[1].strip().split(", "))
    )
    assert config.mtconnect.ports == said
