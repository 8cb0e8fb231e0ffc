"""The virtual agent's documents: MTConnectDevices, MTConnectStreams and MTConnectError of
MTConnect 2.0, laid out as the reference agent lays them (docs/mtconnect-input.md#documents).

Each virtual device is a Device with its Availability, a Controller (EmergencyStop,
ControllerMode, a SYSTEM condition) and one Path (Execution, Program, LineNumber, PartCount).
The Devices document validates against the Institute's MTConnectDevices_2.0 schema
(tests/sim/test_mtconnect_agent.py checks it).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Iterable
from dataclasses import dataclass
from datetime import UTC, datetime

__all__ = [
    "ITEMS",
    "VERSION",
    "ItemDef",
    "Stored",
    "devices_xml",
    "error_xml",
    "ident_of",
    "streams_xml",
]

VERSION = "2.0"


@dataclass(frozen=True)
class ItemDef:
    """One data item of every virtual device (``key`` makes its id: ``<device>_<key>``)."""

    key: str
    type: str
    element: str  # the observation's element name in a streams document
    category: str = "EVENT"
    component: str = "path"  # device, controller or path
    sub_type: str = ""


ITEMS: tuple[ItemDef, ...] = (
    ItemDef("avail", "AVAILABILITY", "Availability", component="device"),
    ItemDef("estop", "EMERGENCY_STOP", "EmergencyStop", component="controller"),
    ItemDef("mode", "CONTROLLER_MODE", "ControllerMode", component="controller"),
    ItemDef("system", "SYSTEM", "", category="CONDITION", component="controller"),
    ItemDef("exec", "EXECUTION", "Execution"),
    ItemDef("program", "PROGRAM", "Program"),
    ItemDef("line", "LINE_NUMBER", "LineNumber", sub_type="ABSOLUTE"),
    ItemDef("parts", "PART_COUNT", "PartCount", sub_type="ALL"),
)

_COMPONENT = {"device": "Device", "controller": "Controller", "path": "Path"}


@dataclass(frozen=True)
class Stored:
    """One observation in the agent's buffer (a condition's ``level`` is set)."""

    sequence: int
    device: int  # index into the agent's devices
    item: ItemDef
    timestamp: datetime
    value: str
    level: str = ""  # Normal, Warning, Fault, Unavailable for a condition
    native_code: str = ""


def ident_of(index: int) -> str:
    """The XML id of device ``index`` (names may hold characters an id may not)."""
    return f"d{index + 1}"


def _time(at: datetime) -> str:
    return at.astimezone(UTC).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


def _document(kind: str, header: dict[str, str]) -> ET.Element:
    root = ET.Element(f"MTConnect{kind}", xmlns=f"urn:mtconnect.org:MTConnect{kind}:{VERSION}")
    ET.SubElement(root, "Header", header)
    return root


def _text(root: ET.Element) -> bytes:
    body: bytes = ET.tostring(root, encoding="utf-8", xml_declaration=False)
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + body


def _header(instance: int, sender: str, buffer_size: int) -> dict[str, str]:
    return {
        "creationTime": _time(datetime.now(UTC)).split(".")[0] + "Z",
        "sender": sender,
        "instanceId": str(instance),
        "version": VERSION,
        "bufferSize": str(buffer_size),
    }


def devices_xml(
    names: list[str], *, instance: int, sender: str, buffer_size: int, only: int | None = None
) -> bytes:
    """The probe answer for devices ``names`` (or only device ``only``: its ids stay those of
    the whole agent's, as streams documents name them)."""
    header = _header(instance, sender, buffer_size)
    header |= {
        "assetBufferSize": "1024",
        "assetCount": "0",
        # 2.0 asks when the device model last changed: it never does here
        "deviceModelChangeTime": header["creationTime"],
    }
    root = _document("Devices", header)
    devices = ET.SubElement(root, "Devices")
    for index, name in enumerate(names):
        if only is not None and index != only:
            continue
        ident = ident_of(index)
        device = ET.SubElement(
            devices, "Device", id=ident, name=name, uuid=f"opendnc-sim-{sender}-{name}"
        )
        ET.SubElement(device, "Description").text = f"virtual machine {name} (opendnc sim)"
        parents = {"device": ET.SubElement(device, "DataItems")}
        controller = ET.SubElement(
            ET.SubElement(device, "Components"), "Controller", id=f"{ident}_cont", name="cont"
        )
        parents["controller"] = ET.SubElement(controller, "DataItems")
        path = ET.SubElement(
            ET.SubElement(controller, "Components"), "Path", id=f"{ident}_path", name="path"
        )
        parents["path"] = ET.SubElement(path, "DataItems")
        for item in ITEMS:
            attrs = {"category": item.category, "id": f"{ident}_{item.key}", "type": item.type}
            if item.sub_type:
                attrs["subType"] = item.sub_type
            ET.SubElement(parents[item.component], "DataItem", attrs)
    return _text(root)


def streams_xml(
    names: list[str],
    observations: Iterable[Stored],
    *,
    instance: int,
    sender: str,
    buffer_size: int,
    first: int,
    last: int,
    next_sequence: int,
    only: int | None = None,
) -> bytes:
    """A current or sample answer holding ``observations`` (of device ``only``, or all)."""
    header = _header(instance, sender, buffer_size)
    header |= {
        "nextSequence": str(next_sequence),
        "firstSequence": str(first),
        "lastSequence": str(last),
    }
    root = _document("Streams", header)
    streams = ET.SubElement(root, "Streams")
    by_device: dict[int, dict[str, list[Stored]]] = {}
    for stored in observations:
        by_device.setdefault(stored.device, {}).setdefault(stored.item.component, []).append(stored)
    for index, name in enumerate(names):
        if only is not None and index != only:
            continue
        ident = ident_of(index)
        device = ET.SubElement(
            streams, "DeviceStream", name=name, uuid=f"opendnc-sim-{sender}-{name}"
        )
        for component, stored_list in by_device.get(index, {}).items():
            suffix = "" if component == "device" else f"_{component[:4]}"
            stream = ET.SubElement(
                device,
                "ComponentStream",
                component=_COMPONENT[component],
                componentId=f"{ident}{suffix}",
            )
            # the schema wants Samples, Events, Condition in this order
            events = [s for s in stored_list if s.item.category == "EVENT"]
            conditions = [s for s in stored_list if s.item.category == "CONDITION"]
            if events:
                parent = ET.SubElement(stream, "Events")
                for s in events:
                    element = ET.SubElement(parent, s.item.element, _attrs(s, ident))
                    element.text = s.value
            if conditions:
                parent = ET.SubElement(stream, "Condition")
                for s in conditions:
                    attrs = _attrs(s, ident) | {"type": s.item.type}
                    if s.native_code:
                        attrs["nativeCode"] = s.native_code
                    element = ET.SubElement(parent, s.level, attrs)
                    if s.value:
                        element.text = s.value
    return _text(root)


def _attrs(stored: Stored, ident: str) -> dict[str, str]:
    attrs = {
        "dataItemId": f"{ident}_{stored.item.key}",
        "sequence": str(stored.sequence),
        "timestamp": _time(stored.timestamp),
    }
    if stored.item.sub_type:
        attrs["subType"] = stored.item.sub_type
    return attrs


def error_xml(code: str, text: str, *, instance: int, sender: str, buffer_size: int) -> bytes:
    """An MTConnectError answer with one error."""
    root = _document("Error", _header(instance, sender, buffer_size))
    error = ET.SubElement(ET.SubElement(root, "Errors"), "Error", errorCode=code)
    error.text = text
    return _text(root)
