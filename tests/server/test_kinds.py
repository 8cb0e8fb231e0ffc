"""Machine kinds: each kind's schema has only its fields, its connector and capabilities come
from its module, errors name the key, and older configuration files keep working."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from opendnc.server.config.shop import ConfigError, parse_config
from opendnc.server.kinds.base import Capabilities
from opendnc.server.kinds.capabilities import capabilities_of
from opendnc.server.kinds.haas_ngc import HaasNgcMachine
from opendnc.server.kinds.haas_serial import HaasSerialMachine
from opendnc.server.kinds.lsv2 import Lsv2Machine
from opendnc.server.kinds.mtconnect import MtconnectMachine
from opendnc.server.kinds.opcua import OpcuaMachine
from opendnc.server.kinds.registry import KINDS, connector_for, spec_of
from opendnc.server.kinds.serial import SerialMachine

SHOP = """
[[machines]]
name = "tnc"
kind = "lsv2"
host = "127.0.0.1"
receive_folder = "TNC:/out"

[[machines]]
name = "ngc"
kind = "haas_ngc"
host = "127.0.0.1"
dprnt = "tcp://127.0.0.1:5052"

[[machines]]
name = "serial"
kind = "haas_serial"
host = ""
serial = "socket://127.0.0.1:7000"
dripfeed = true
mdc = true

[[machines]]
name = "agent"
kind = "mtconnect"
url = "http://127.0.0.1:5000/"
device = "dmu50"

[[machines]]
name = "tape"
kind = "serial"
serial = "socket://127.0.0.1:7001"
profile = "okuma-osp"
baud = 4800
eob = "lf"
tv_check = true
dripfeed = true
verify = "punch"

[[machines]]
name = "umati"
kind = "opcua"
endpoint = "opc.tcp://127.0.0.1:4840"
machine = "DMU 50"
"""


def test_each_machine_gets_its_kinds_schema_with_only_its_fields(tmp_path: Path) -> None:
    tnc, ngc, serial, agent, tape, umati = parse_config(SHOP, base=tmp_path).machines
    assert isinstance(tnc, Lsv2Machine)
    assert tnc.port == 19000
    assert isinstance(ngc, HaasNgcMachine)
    assert ngc.mdc_port == 5051
    assert isinstance(serial, HaasSerialMachine)
    assert serial.dripfeed
    fields = {type(m): {f.name for f in dataclasses.fields(m)} for m in (tnc, ngc, serial)}
    assert "dripfeed" not in fields[Lsv2Machine] | fields[HaasNgcMachine]
    assert "port" not in fields[HaasSerialMachine] | fields[HaasNgcMachine]
    assert "receive_folder" not in fields[HaasSerialMachine] | fields[HaasNgcMachine]
    assert isinstance(agent, MtconnectMachine)
    assert (agent.url, agent.device, agent.streaming) == ("http://127.0.0.1:5000", "dmu50", True)
    assert isinstance(tape, SerialMachine)
    # the named profile with the machine's overrides; the rest is the profile's own
    assert (tape.tape.name, tape.tape.baud, tape.tape.eob.value) == ("okuma-osp", 4800, "lf")
    assert tape.tape.tv_check
    assert tape.tape.leader == 600  # okuma-osp's feed, not overridden
    assert (tape.dripfeed, tape.verify) == (True, "punch")
    own = {f.name for f in dataclasses.fields(tape)}
    assert not own & {"mdc", "dprnt", "profile", "port", "receive_folder"}
    assert isinstance(umati, OpcuaMachine)
    assert (umati.endpoint, umati.machine, umati.security_policy) == (
        "opc.tcp://127.0.0.1:4840",
        "DMU 50",
        "None",
    )
    assert sorted(spec_of(m).kind for m in (tnc, ngc, serial, agent, tape, umati)) == sorted(KINDS)


def test_capabilities_come_from_the_kind_module(tmp_path: Path) -> None:
    tnc, ngc, serial, agent, tape, _umati = parse_config(SHOP, base=tmp_path).machines
    assert capabilities_of(tnc).file_browser
    assert capabilities_of(tnc).receive
    assert not capabilities_of(tnc).dripfeed
    assert not capabilities_of(tnc).dprnt
    assert capabilities_of(ngc).dprnt
    assert not capabilities_of(ngc).file_browser
    assert capabilities_of(serial).dripfeed
    assert capabilities_of(serial).receive
    assert "part_count" in capabilities_of(serial).status_fields  # mdc = true
    without_mdc = dataclasses.replace(serial, mdc=False)
    assert capabilities_of(without_mdc).status_fields == frozenset()
    assert capabilities_of(agent) == Capabilities(
        status_fields=capabilities_of(agent).status_fields
    )
    assert "part_count" in capabilities_of(agent).status_fields
    # a tape control reports nothing: its status is what the server drives on the port
    assert capabilities_of(tape).receive
    assert capabilities_of(tape).dripfeed
    assert not capabilities_of(dataclasses.replace(tape, dripfeed=False)).dripfeed
    assert not capabilities_of(tape).file_browser
    assert "part_count" not in capabilities_of(tape).status_fields


def test_the_connector_is_the_kinds(tmp_path: Path) -> None:
    from opendnc.server.kinds.haas_ngc.connector import HaasNgcConnector
    from opendnc.server.kinds.haas_serial.connector import HaasSerialConnector
    from opendnc.server.kinds.lsv2.connector import Lsv2Connector
    from opendnc.server.kinds.mtconnect.connector import MtconnectConnector
    from opendnc.server.kinds.serial.connector import TapeConnector

    tnc, ngc, serial, agent, tape, _umati = parse_config(SHOP, base=tmp_path).machines
    assert isinstance(connector_for(tnc), Lsv2Connector)
    assert isinstance(connector_for(ngc), HaasNgcConnector)
    assert isinstance(connector_for(serial), HaasSerialConnector)
    assert isinstance(connector_for(agent), MtconnectConnector)
    assert isinstance(connector_for(tape), TapeConnector)


@pytest.mark.parametrize(
    ("entry", "key", "words"),
    [
        ('kind = "lsv2"\nhost = "h"\nport = "x"', "port", "expected int"),
        ('kind = "lsv2"\nhost = "h"\ndripfeed = true', "dripfeed", "haas_serial, serial"),
        ('kind = "lsv2"\nhost = "h"\ndprnt = "serial"', "dprnt", "Haas feature"),
        ('kind = "haas_ngc"\nhost = "h"\nmdc = true', "mdc", "only for haas_serial"),
        ('kind = "haas_ngc"\nhost = "h"\ndprnt = "serial"', "dprnt", "haas_serial"),
        ('kind = "haas_serial"\nserial = "/x"\nreceive_folder = "TNC:/"', "receive_folder", "lsv2"),
        ('kind = "haas_serial"\nserial = "/dev/x"\nmdc_interval = 0', "mdc_interval", "seconds"),
        ('kind = "haas_serial"\nserial = "/dev/x"\nportt = 1', "portt", "unknown key"),
        ('kind = "fanuc"\nhost = "h"', "kind", "expected one of"),
        ('kind = "mtconnect"\nurl = "10.0.0.3:5000"', "url", "http://HOST:PORT"),
        ('kind = "mtconnect"\nurl = "http://h:5000"\ndevice = "a/b"', "device", "device's name"),
        ('kind = "serial"', "serial", "device or URL"),
        ('kind = "serial"\nserial = "/x"\nprofile = "fanuc-9"', "profile", "fanuc-0i, fanuc-30i"),
        ('kind = "serial"\nserial = "/x"\nbaud = 9601', "baud", "standard rate"),
        ('kind = "serial"\nserial = "/x"\ncode = "ascii"', "code", "iso, eia"),
        ('kind = "serial"\nserial = "/x"\neob = "crcr"', "eob", "lf, crlf, cr, lfcrcr"),
        ('kind = "serial"\nserial = "/x"\nverify = "read"', "verify", '"punch"'),
        ('kind = "serial"\nserial = "/x"\ncontrol = "okuma"', "control", "fanuc-mill"),
        ('kind = "serial"\nserial = "/x"\nmdc = true', "mdc", "only for haas_serial"),
    ],
)  # fmt: skip
def test_errors_name_the_key(entry: str, key: str, words: str, tmp_path: Path) -> None:
    first = '[[machines]]\nname = "a"\nkind = "lsv2"\nhost = "h"\n'
    text = f'{first}\n[[machines]]\nname = "m"\n{entry}\n'
    with pytest.raises(ConfigError) as caught:
        parse_config(text, base=tmp_path)
    assert caught.value.key == f"machines[1].{key}"
    assert words in str(caught.value)


def test_files_written_for_the_flat_schema_keep_working(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    # Every key used to be taken for every kind; those that meant nothing still do nothing.
    text = """
[[machines]]
name = "vf"
kind = "haas_serial"
serial = "/dev/ttyUSB0"
host = "10.0.0.5"
port = 19000
share = ""
dripfeed = false

[[machines]]
name = "tnc"
kind = "lsv2"
host = "10.0.0.6"
dripfeed = false
mdc_port = 5051
"""
    vf, tnc = parse_config(text, base=tmp_path).machines
    assert vf.kind == "haas_serial"
    assert tnc.kind == "lsv2"
    assert "machines[0].host: only for haas_ngc and lsv2; ignored" in caplog.text
    assert "machines[1].mdc_port" in caplog.text
