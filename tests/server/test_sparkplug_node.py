"""The Sparkplug B edge node's messages without a broker: births, data by exception with
aliases, deaths, ``seq`` wrapping, the bdSeq store, the STATE parser and the configuration.
Every payload is read back with the tests' own decoder (tests/server/spb_decoder.py)."""

from __future__ import annotations

import json
from dataclasses import replace
from datetime import UTC, datetime, timedelta
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st
from sqlalchemy.orm import Session, sessionmaker

from tests.peers import require_module

require_module("pysparkplug")
require_module("google.protobuf")

from opendnc.server.config.shop import ConfigError, parse_config  # noqa: E402
from opendnc.server.core.events import EventBus, LeaseChanged, MachineStatusChanged  # noqa: E402
from opendnc.server.core.status import MachineStatus  # noqa: E402
from opendnc.server.outputs.sparkplug import (  # noqa: E402
    DEVICE_METRICS,
    REBIRTH,
    Outgoing,
    SparkplugNode,
    host_state,
)
from opendnc.server.outputs.sparkplug_store import next_bd_seq  # noqa: E402
from tests.server import spb_decoder as spb  # noqa: E402

BASE = """
[server]
name = "dnc-7"
[library]
path = "lib"
[[machines]]
name = "mill-1"
kind = "lsv2"
host = "127.0.0.1"
[[machines]]
name = "mill-2"
kind = "lsv2"
host = "127.0.0.1"
"""

START = datetime(2026, 11, 27, 6, 0, tzinfo=UTC)


def node(tmp_path: Path, extra: str = "") -> SparkplugNode:
    config = parse_config(
        BASE + '[sparkplug]\nurl = "mqtt://127.0.0.1"\ngroup = "plant1"\n' + extra, base=tmp_path
    )
    assert config.sparkplug is not None
    spc = replace(config.sparkplug, node=config.sparkplug.node or config.server.name)
    made = SparkplugNode(spc, ["mill-1", "mill-2"], EventBus(), lambda: 0)
    made._spb = __import__("pysparkplug")  # what start() does, without a broker
    made.bd_seq = 7
    return made


def status(machine: str, n: int = 0, **kw: object) -> MachineStatusChanged:
    fields: dict[str, object] = {
        "at": START + timedelta(seconds=n),
        "available": True,
        "execution": "READY",
        "program": "PART.H",
        "part_count": 3,
        "overrides": {"feed": 100.0},
    }
    fields.update(kw)
    return MachineStatusChanged(machine, True, MachineStatus(**fields))  # type: ignore[arg-type]


def run(host: spb.Host, messages: list[Outgoing]) -> list[str]:
    """Feed the node's messages to the test's host; the kinds it saw."""
    before = len(host.seen)
    for message in messages:
        host.take(message.topic, message.payload)
    return [f"{s.kind}:{s.device}" if s.device else s.kind for s in host.seen[before:] if s.kind]


def test_birth_data_by_exception_and_death(tmp_path: Path) -> None:
    edge = node(tmp_path)
    host = spb.Host("plant1")
    assert run(host, edge.births()) == ["NBIRTH"]
    nbirth = host.of("NBIRTH")[0].payload.by_name()
    assert nbirth["bdSeq"].value == 7
    assert nbirth["bdSeq"].datatype == spb.INT64
    assert nbirth[REBIRTH].value is False
    assert nbirth[REBIRTH].datatype == spb.BOOLEAN

    # Gained, not read yet: no device until its first status.
    edge.take(LeaseChanged("mill-1", "dnc-7", True))
    assert edge.changes() == []
    edge.take(status("mill-2"))  # a machine this server does not serve: nothing
    edge.take(status("mill-1"))
    assert run(host, edge.changes()) == ["DBIRTH:mill-1"]
    birth = host.of("DBIRTH", device="mill-1")[0].payload
    assert [m.name for m in birth.metrics] == [name for name, _kind in DEVICE_METRICS]
    values = birth.by_name()
    assert values["state"].value == "ready"
    assert values["availability"].value == "AVAILABLE"
    assert values["program"].value == "PART.H"
    assert values["part_count"].value == 3
    assert values["part_count"].datatype == spb.INT64
    assert values["feed_override"].value == 100.0
    assert values["alarm"].value is False
    assert values["line_number"].is_null  # a control that does not tell: null, typed
    assert values["line_number"].datatype == spb.INT64
    assert values["state"].timestamp == int(START.timestamp() * 1000)
    # Aliases unique across the node and its devices (the node's own included).
    aliases = [m.alias for m in nbirth.values() if m.alias is not None]
    aliases += [m.alias for m in birth.metrics]
    assert len(set(aliases)) == len(aliases)

    # The same status again: nothing; one item changes: that metric alone, by alias.
    edge.take(status("mill-1", 1))
    assert edge.changes() == []
    edge.take(status("mill-1", 2, part_count=4))
    assert run(host, edge.changes()) == ["DDATA:mill-1"]
    data = host.of("DDATA")[-1].payload
    assert [(m.name, m.value) for m in data.metrics] == [(None, 4)]
    assert host.device("dnc-7", "mill-1").values["part_count"] == 4  # type: ignore[union-attr]

    # An alarm: the state, the alarm flag and the text change together.
    edge.take(status("mill-1", 3, part_count=4, errors=("1023 SPINDLE",)))
    run(host, edge.changes())
    device = host.device("dnc-7", "mill-1")
    assert device is not None
    assert device.values["state"] == "alarm"
    assert device.values["alarm"] is True
    assert device.values["alarms"] == "1023 SPINDLE"

    # Released: DDEATH, and its statuses are not this node's any more.
    edge.take(LeaseChanged("mill-1", "dnc-7", False))
    edge.take(status("mill-1", 4))
    assert run(host, edge.changes()) == ["DDEATH:mill-1"]
    assert not device.alive


def test_seq_wraps_after_255_and_a_rebirth_starts_again_at_zero(tmp_path: Path) -> None:
    edge = node(tmp_path)
    host = spb.Host("plant1")
    run(host, edge.births())
    edge.take(LeaseChanged("mill-1", "dnc-7", True))
    for n in range(300):
        edge.take(status("mill-1", n, part_count=n))
        run(host, edge.changes())  # the host checks every seq as it takes it
    seqs = [s.payload.seq for s in host.seen[1:]]
    assert seqs[:3] == [1, 2, 3]
    assert seqs[254:257] == [255, 0, 1]
    assert len(seqs) == 300
    # A rebirth: NBIRTH seq 0, the same bdSeq (same session), every device born again.
    edge.take(LeaseChanged("mill-2", "dnc-7", True))
    edge.take(status("mill-2"))
    assert run(host, edge.births()) == ["NBIRTH", "DBIRTH:mill-1", "DBIRTH:mill-2"]
    assert [s.payload.seq for s in host.seen[-3:]] == [0, 1, 2]
    assert host.of("NBIRTH")[-1].payload.by_name()["bdSeq"].value == 7


def test_a_device_lives_while_its_control_answers(tmp_path: Path) -> None:
    """Sparkplug 3.0, 5.7: an edge node that loses its device publishes the device's DDEATH.
    A machine whose control does not answer is not born (a DBIRTH says the device is online);
    it is born with its first answered status, dies when the link is lost, and is born again
    (with every metric, unknown ones null) when the control answers again."""
    edge = node(tmp_path)
    host = spb.Host("plant1")
    run(host, edge.births())
    edge.take(LeaseChanged("mill-2", "dnc-7", True))
    edge.take(MachineStatusChanged("mill-2", False, None, last_error="no route"))
    assert run(host, edge.changes()) == []
    edge.take(status("mill-2", program="", part_count=None, overrides={}))
    assert run(host, edge.changes()) == ["DBIRTH:mill-2"]
    values = host.of("DBIRTH", device="mill-2")[0].payload.by_name()
    assert values["state"].value == "ready"
    assert values["availability"].value == "AVAILABLE"
    assert values["alarm"].value is False
    assert values["program"].is_null
    assert values["part_count"].is_null

    lost = MachineStatus(at=START, available=False, message="connection refused")
    edge.take(MachineStatusChanged("mill-2", False, lost, last_error="connection refused"))
    assert run(host, edge.changes()) == ["DDEATH:mill-2"]
    assert not host.device("dnc-7", "mill-2").alive  # type: ignore[union-attr]
    edge.take(MachineStatusChanged("mill-2", False, None, last_error="no route"))  # still away
    assert run(host, edge.changes()) == []
    edge.take(status("mill-2", 1))
    assert run(host, edge.changes()) == ["DBIRTH:mill-2"]
    assert host.device("dnc-7", "mill-2").values["program"] == "PART.H"  # type: ignore[union-attr]
    # A rebirth while it is away bears only the node and the devices that answer.
    edge.take(MachineStatusChanged("mill-2", False, lost, last_error="connection refused"))
    assert run(host, edge.changes()) == ["DDEATH:mill-2"]
    assert run(host, edge.births()) == ["NBIRTH"]


def test_ndeath_carries_the_sessions_bd_seq(tmp_path: Path) -> None:
    edge = node(tmp_path)
    death = edge.death()
    assert death.topic == "spBv1.0/plant1/NDEATH/dnc-7"
    assert death.qos == 1
    assert spb.decode(death.payload).by_name()["bdSeq"].value == 7


def test_rebirth_command_and_primary_host_state(tmp_path: Path) -> None:
    edge = node(tmp_path, 'primary_host = "scada"\n')
    assert not edge.host_online
    edge.received("spBv1.0/STATE/scada", spb.state_payload(True, 1000))
    assert edge.host_online
    edge.received("spBv1.0/STATE/scada", spb.state_payload(False, 999))  # older: ignored
    assert edge.host_online
    edge.received("spBv1.0/plant1/NCMD/dnc-7", spb.encode_command({REBIRTH: True}, 1))
    assert edge._rebirth
    edge.received("spBv1.0/plant1/NCMD/dnc-7", b"\xff\x00not protobuf")  # logged, ignored


@given(st.binary(max_size=200))
def test_state_parser_takes_any_bytes(raw: bytes) -> None:
    got = host_state(raw)
    assert got is None or (isinstance(got[0], bool) and isinstance(got[1], int))


@given(st.booleans(), st.integers(min_value=0, max_value=2**63))
def test_state_parser_reads_what_a_host_sends(online: bool, stamp: int) -> None:
    assert host_state(json.dumps({"online": online, "timestamp": stamp}).encode()) == (
        online,
        stamp,
    )
    assert host_state(b"ONLINE" if online else b"OFFLINE") == (online, 0)


def test_bd_seq_counts_per_node_and_wraps(sessions: sessionmaker[Session]) -> None:
    got = [next_bd_seq(sessions, "plant1", "dnc-1") for _ in range(258)]
    assert got[:3] == [0, 1, 2]
    assert got[255:] == [255, 0, 1]
    assert next_bd_seq(sessions, "plant1", "dnc-2") == 0  # each node its own
    assert next_bd_seq(sessions, "plant2", "dnc-1") == 0


def test_configuration(tmp_path: Path) -> None:
    config = parse_config(
        BASE + '[sparkplug]\nurl = "mqtts://broker:8883"\ngroup = "g"\nusername = "u"\n',
        base=tmp_path,
    )
    assert config.sparkplug is not None
    assert config.sparkplug.node == ""  # the server's name, filled in at build (serve --name)
    assert config.sparkplug.broker.tls
    assert config.sparkplug.broker.port == 8883
    assert config.sparkplug.primary_host == ""
    for bad, key in (
        ('group = "a/b"', "sparkplug.group"),
        ('group = "g"\nnode = "n#"', "sparkplug.node"),
        ('group = "g"\nprimary_host = "+"', "sparkplug.primary_host"),
        ('group = "g"\nprefix = "x"', "sparkplug.prefix"),
        ('group = ""', "sparkplug.group"),
    ):
        with pytest.raises(ConfigError) as caught:
            parse_config(BASE + f'[sparkplug]\nurl = "mqtt://h"\n{bad}\n', base=tmp_path)
        assert caught.value.key == key, bad


def test_the_count_goes_on_in_memory_while_the_database_is_away(tmp_path: Path) -> None:
    import asyncio

    from sqlalchemy.exc import OperationalError

    edge = node(tmp_path)
    edge.bd_seq = 254

    def away() -> int:
        raise OperationalError("SELECT", {}, Exception("connection refused"))

    edge.next_bd_seq = away
    asyncio.run(edge._take_bd_seq())
    assert edge.bd_seq == 255
    asyncio.run(edge._take_bd_seq())
    assert edge.bd_seq == 0
