"""An MTConnect agent's documents as typed data (opendnc.mtconnect, docs/mtconnect-input.md):
probe, streams and error documents, the multipart stream, and one device's state."""

from __future__ import annotations

import pytest

from tests.peers import require_module

require_module("lxml")

from opendnc.errors import RemoteProtocolError  # noqa: E402
from opendnc.mtconnect.device_state import DeviceState, pick_device  # noqa: E402
from opendnc.mtconnect.documents import (  # noqa: E402
    AgentRefused,
    Condition,
    parse_devices,
    parse_document,
    parse_streams,
)
from opendnc.mtconnect.multipart import MultipartSplitter, boundary_of  # noqa: E402

# Written for these tests in the layout of MTConnect Part 1/2 (a 1.3 namespace: the parser
# reads any version's): an agent device, a mill with a path, a second part counter (TARGET).
PROBE = b"""<?xml version="1.0" encoding="UTF-8"?>
<MTConnectDevices xmlns="urn:mtconnect.org:MTConnectDevices:1.3">
  <Header creationTime="2026-01-01T00:00:00Z" sender="a" instanceId="17" version="1.3.0"
          bufferSize="131072" assetBufferSize="1024" assetCount="0"/>
  <Devices>
    <Agent id="agent" name="Agent" uuid="a-1"><DataItems>
      <DataItem id="agent_avail" type="AVAILABILITY" category="EVENT"/>
      <DataItem id="agent_uri" type="ADAPTER_URI" category="EVENT"/>
    </DataItems></Agent>
    <Device id="m" name="mill-7" uuid="u-7">
      <DataItems><DataItem id="avail" type="AVAILABILITY" category="EVENT"/></DataItems>
      <Components><Controller id="c" name="controller">
        <DataItems>
          <DataItem id="estop" type="EMERGENCY_STOP" category="EVENT"/>
          <DataItem id="mode" type="CONTROLLER_MODE" category="EVENT"/>
          <DataItem id="sys" type="SYSTEM" category="CONDITION"/>
        </DataItems>
        <Components><Path id="p" name="path"><DataItems>
          <DataItem id="exec" type="EXECUTION" category="EVENT"/>
          <DataItem id="prog" type="PROGRAM" category="EVENT"/>
          <DataItem id="ln" type="LINE_NUMBER" subType="ABSOLUTE" category="EVENT"/>
          <DataItem id="target" type="PART_COUNT" subType="TARGET" category="EVENT"/>
          <DataItem id="pc" type="PART_COUNT" subType="ALL" category="EVENT"/>
        </DataItems></Path></Components>
      </Controller></Components>
    </Device>
  </Devices>
</MTConnectDevices>"""


def streams(instance: int, first: int, next_: int, body: str) -> bytes:
    """A streams document of device mill-7 holding ``body`` (observations by component)."""
    return f"""<?xml version="1.0" encoding="UTF-8"?>
<MTConnectStreams xmlns="urn:mtconnect.org:MTConnectStreams:1.3">
  <Header creationTime="2026-01-01T00:00:00Z" sender="a" instanceId="{instance}"
          version="1.3.0" bufferSize="131072" nextSequence="{next_}"
          firstSequence="{first}" lastSequence="{next_ - 1}"/>
  <Streams><DeviceStream name="mill-7" uuid="u-7">{body}</DeviceStream></Streams>
</MTConnectStreams>""".encode()


def event(tag: str, ident: str, sequence: int, value: str) -> str:
    return (
        f'<ComponentStream component="Path" componentId="p"><Events><{tag} dataItemId="{ident}"'
        f' sequence="{sequence}" timestamp="2026-01-01T00:00:00Z">{value}</{tag}></Events>'
        "</ComponentStream>"
    )


def condition(level: str, sequence: int, code: str = "", text: str = "", cid: str = "") -> str:
    native = (f' nativeCode="{code}"' if code else "") + (f' conditionId="{cid}"' if cid else "")
    return (
        '<ComponentStream component="Controller" componentId="c"><Condition>'
        f'<{level} dataItemId="sys" type="SYSTEM" sequence="{sequence}"'
        f' timestamp="2026-01-01T00:00:00Z"{native}>{text}</{level}></Condition>'
        "</ComponentStream>"
    )


CURRENT = streams(
    17,
    1,
    40,
    event("Availability", "avail", 3, "AVAILABLE")
    + event("Execution", "exec", 30, "ACTIVE")
    + event("Program", "prog", 29, "O1234")
    + event("LineNumber", "ln", 39, "120")
    + event("PartCount", "target", 5, "500")
    + event("PartCount", "pc", 31, "41")
    + event("ControllerMode", "mode", 4, "AUTOMATIC")
    + event("EmergencyStop", "estop", 6, "ARMED")
    + condition("Normal", 7),
)


def test_a_probe_names_the_devices_and_their_items() -> None:
    devices = parse_devices(PROBE)
    assert devices.header.instance_id == 17
    assert [d.name for d in devices.devices] == ["Agent", "mill-7"]
    mill = devices.devices[1]
    assert [(i.id, i.type, i.sub_type) for i in mill.items][-2:] == [
        ("target", "PART_COUNT", "TARGET"),
        ("pc", "PART_COUNT", "ALL"),
    ]
    assert {i.category for i in mill.items} == {"EVENT", "CONDITION"}
    # the agent's own device is not a machine: the one real device is picked
    assert pick_device(devices, "") == "mill-7"
    with pytest.raises(RemoteProtocolError, match="no device 'lathe'"):
        pick_device(devices, "lathe")


def test_a_streams_document_reads_header_and_observations() -> None:
    document = parse_streams(CURRENT)
    assert (document.header.first_sequence, document.header.next_sequence) == (1, 40)
    assert document.header.last_sequence == 39
    pc = next(o for o in document.observations if o.data_item_id == "pc")
    assert (pc.sequence, pc.tag, pc.value, pc.device) == (31, "PartCount", "41", "mill-7")
    normal = document.observations[-1]
    assert normal.condition == Condition("Normal")


def test_the_device_state_maps_by_type_and_skips_the_target_counter() -> None:
    state = DeviceState(parse_devices(PROBE), "")
    state.load(parse_streams(CURRENT))
    snap = state.snapshot()
    assert (snap.availability, snap.execution, snap.program) == ("AVAILABLE", "ACTIVE", "O1234")
    assert (snap.line, snap.part_count, snap.controller_mode) == (120, 41, "AUTOMATIC")
    assert snap.emergency_stop == "ARMED"
    assert snap.faults == ()
    assert state.last_sequence == 39


def test_a_resent_observation_does_not_count_twice() -> None:
    state = DeviceState(parse_devices(PROBE), "mill-7")
    state.load(parse_streams(CURRENT))
    more = parse_streams(streams(17, 1, 42, event("PartCount", "pc", 40, "42")))
    assert state.update(more) == 1
    # the same observation again (a resumed stream), then an older one: both dropped
    assert state.update(more) == 0
    older = parse_streams(streams(17, 1, 42, event("PartCount", "pc", 35, "40")))
    assert state.update(older) == 0
    assert state.snapshot().part_count == 42


@pytest.mark.parametrize(
    ("value", "read"),
    [
        ("1e300", None),  # would overflow the status timeline's Integer column
        ("3000000000", None),
        ("2147483648", None),
        ("-5", None),
        ("nan", None),
        ("inf", None),
        ("2.5", None),
        ("12a", None),
        ("2147483647", 2**31 - 1),
        ("7.0", 7),
        ("0", 0),
    ],
)
def test_a_count_out_of_range_or_not_whole_reads_as_unavailable(
    value: str, read: int | None
) -> None:
    state = DeviceState(parse_devices(PROBE), "mill-7")
    state.load(parse_streams(CURRENT))
    state.update(parse_streams(streams(17, 1, 42, event("PartCount", "pc", 40, value))))
    assert state.snapshot().part_count == read


def test_conditions_become_faults_with_their_text_and_clear_by_code() -> None:
    state = DeviceState(parse_devices(PROBE), "mill-7")
    state.load(parse_streams(CURRENT))
    body = (
        condition("Fault", 40, "1010", "SPINDLE OVERLOAD")
        + condition("Fault", 41, "2020", "DOOR OPEN")
        + condition("Warning", 42, "9", "LOW OIL")
    )
    state.update(parse_streams(streams(17, 1, 43, body)))
    snap = state.snapshot()
    assert snap.faults == ("1010 SPINDLE OVERLOAD", "2020 DOOR OPEN")
    assert snap.warnings == ("9 LOW OIL",)
    state.update(parse_streams(streams(17, 1, 44, condition("Normal", 43, "1010"))))
    assert state.snapshot().faults == ("2020 DOOR OPEN",)
    state.update(parse_streams(streams(17, 1, 45, condition("Normal", 44))))
    assert state.snapshot().faults == ()
    assert state.snapshot().warnings == ()


def test_a_condition_id_tells_activations_of_one_code_apart() -> None:
    # MTConnect 2.3: two activations of code 500 at once, cleared one by one by their id
    state = DeviceState(parse_devices(PROBE), "mill-7")
    state.load(parse_streams(CURRENT))
    body = condition("Fault", 40, "500", "AXIS X", cid="a1") + condition(
        "Fault", 41, "500", "AXIS Y", cid="a2"
    )
    state.update(parse_streams(streams(17, 1, 42, body)))
    assert state.snapshot().faults == ("500 AXIS X", "500 AXIS Y")
    state.update(parse_streams(streams(17, 1, 43, condition("Normal", 42, "500", cid="a1"))))
    assert state.snapshot().faults == ("500 AXIS Y",)


def test_a_new_instance_is_refused_by_the_state() -> None:
    state = DeviceState(parse_devices(PROBE), "mill-7")
    with pytest.raises(RemoteProtocolError, match="restarted"):
        state.load(parse_streams(streams(18, 1, 2, "")))


def test_an_error_document_is_the_agents_refusal_with_its_codes() -> None:
    error = b"""<MTConnectError xmlns="urn:mtconnect.org:MTConnectError:1.3">
      <Header creationTime="2026-01-01T00:00:00Z" sender="a" instanceId="3" version="1.3"
              bufferSize="16"/>
      <Errors><Error errorCode="OUT_OF_RANGE">'from' must be greater than 1</Error></Errors>
    </MTConnectError>"""
    with pytest.raises(AgentRefused, match="OUT_OF_RANGE") as caught:
        parse_document(error)
    assert caught.value.codes == ("OUT_OF_RANGE",)
    assert "'from' must be greater than 1" in str(caught.value)


@pytest.mark.parametrize(
    "document",
    [
        # entity expansion ("billion laughs") and an external entity: refused unread
        b'<?xml version="1.0"?><!DOCTYPE x [<!ENTITY a "aaaaaaaaaa"><!ENTITY b "&a;&a;&a;">]>'
        b"<MTConnectStreams>&b;</MTConnectStreams>",
        b'<!DOCTYPE x [<!ENTITY e SYSTEM "file:///etc/passwd">]><MTConnectDevices>&e;'
        b"</MTConnectDevices>",
        b"",
        b"<MTConnectStreams><Header/></MTConnectStreams>",  # no instanceId
        b'<MTConnectStreams><Header instanceId="x"/></MTConnectStreams>',
        b"<html><body>proxy error</body></html>",
        b"<MTConnectStreams>",
        # nesting past libxml2's limit (huge_tree off), and a number past Python's int digits
        b"<MTConnectStreams>" + b"<a>" * 5000 + b"</a>" * 5000 + b"</MTConnectStreams>",
        b'<MTConnectStreams><Header instanceId="' + b"9" * 5000 + b'"/></MTConnectStreams>',
    ],
)
def test_bad_documents_are_typed_errors(document: bytes) -> None:
    with pytest.raises(RemoteProtocolError):
        parse_document(document)


def _part(body: bytes, boundary: bytes = b"b0undary") -> bytes:
    return (
        b"--" + boundary + b"\r\nContent-type: text/xml\r\nContent-length: "
        + str(len(body)).encode() + b"\r\n\r\n" + body + b"\r\n"
    )  # fmt: skip


def test_the_multipart_stream_is_cut_by_length_at_any_chunking() -> None:
    # the second document holds the boundary itself: lengths, not searches, cut the parts
    documents = [b"<a/>", b"--b0undary\r\n<b/>", b""]
    wire = b"".join(_part(d) for d in documents) + b"--b0undary--\r\n"
    for size in (1, 2, 7, len(wire)):
        splitter = MultipartSplitter("b0undary")
        got = []
        for at in range(0, len(wire), size):
            got += splitter.feed(wire[at : at + size])
        assert got == documents
        assert splitter.closed


def test_the_boundary_comes_from_the_content_type() -> None:
    assert boundary_of("multipart/mixed;boundary=abc123") == "abc123"
    assert boundary_of('multipart/x-mixed-replace; boundary="q-1"') == "q-1"
    assert boundary_of("text/xml") is None
    with pytest.raises(RemoteProtocolError):
        boundary_of("multipart/mixed")


@pytest.mark.parametrize(
    ("wire", "problem"),
    [
        (b"--other\r\nContent-length: 1\r\n\r\nx\r\n", "expected the boundary"),
        (b"--b0undary\r\nContent-type: text/xml\r\n\r\n<a/>", "without Content-length"),
        (b"--b0undary\r\nContent-length: -4\r\n\r\n", "out of bounds"),
        (b"--b0undary\r\nContent-length: 4x\r\n\r\n", "not a number"),
        (b"--b0undary\r\n" + b"X-Pad: y\r\n" * 600, "longer than 4096"),
    ],
)
def test_a_broken_multipart_stream_is_a_typed_error(wire: bytes, problem: str) -> None:
    with pytest.raises(RemoteProtocolError, match=problem):
        MultipartSplitter("b0undary").feed(wire)
