"""MTConnect response documents (probe, current, sample, error) as typed data: sans-IO, fed
bytes, no HTTP inside (docs/mtconnect-input.md#documents).

The parser is lxml configured for input from the network: no DTD is loaded, no entity is
resolved, nothing is fetched, and the "huge tree" limits of libxml2 stay on. A document that
declares a DOCTYPE at all is refused before it is parsed (an agent never sends one; the
entity-expansion attacks need one). Every failure is a
:class:`~opendnc.errors.RemoteProtocolError`; an agent's MTConnectError document is an
:class:`AgentRefused` carrying its error codes.

Elements are matched by local name: agents declare the namespace of their own version
(``urn:mtconnect.org:MTConnectStreams:1.3`` ... ``:2.x``), and the layout this module reads is
the same in all of them.
"""

from __future__ import annotations

from dataclasses import dataclass

from lxml import etree

from opendnc.errors import DncError, RemoteProtocolError

__all__ = [
    "MAX_DOCUMENT",
    "UNAVAILABLE",
    "AgentRefused",
    "Condition",
    "DataItem",
    "Device",
    "Devices",
    "Header",
    "Observation",
    "Streams",
    "parse_devices",
    "parse_document",
    "parse_streams",
]

MAX_DOCUMENT = 16 * 1024 * 1024
"""The largest document taken (bytes): a full buffer of a busy agent is far less."""

UNAVAILABLE = "UNAVAILABLE"
"""The value every data item reads when its source cannot tell."""

_CONDITION_LEVELS = frozenset({"Normal", "Warning", "Fault", "Unavailable"})


class AgentRefused(DncError):
    """The agent answered with an MTConnectError document (``codes``: its errorCode words,
    e.g. ``OUT_OF_RANGE``, ``NO_DEVICE``, ``UNSUPPORTED``)."""

    def __init__(self, codes: tuple[str, ...], text: str) -> None:
        self.codes = codes
        self.text = text
        detail = f": {text}" if text else ""
        super().__init__(f"MTConnect agent refused the request ({', '.join(codes)}){detail}")


@dataclass(frozen=True)
class Header:
    """A document's header: who answered, and where the agent's buffer stands."""

    instance_id: int  # changes when the agent restarts
    version: str = ""
    sender: str = ""
    first_sequence: int = 0  # streams only: the oldest observation still in the buffer
    last_sequence: int = 0  # streams only: the newest one
    next_sequence: int = 0  # streams only: where the next sample request starts


@dataclass(frozen=True)
class DataItem:
    """One data item a probe declares (``device`` is the name of its device)."""

    id: str
    type: str  # EXECUTION, PART_COUNT, SYSTEM, ...
    category: str  # EVENT, SAMPLE or CONDITION
    device: str
    name: str = ""
    sub_type: str = ""


@dataclass(frozen=True)
class Device:
    """A device of a probe and its data items, in document order."""

    name: str
    uuid: str
    items: tuple[DataItem, ...]


@dataclass(frozen=True)
class Devices:
    """A probe answer (MTConnectDevices)."""

    header: Header
    devices: tuple[Device, ...]


@dataclass(frozen=True)
class Condition:
    """The state of a condition entry: ``level`` Normal, Warning, Fault or Unavailable."""

    level: str
    native_code: str = ""
    native_severity: str = ""
    qualifier: str = ""
    condition_id: str = ""  # MTConnect 2.3+: one activation, from Warning/Fault to Normal


@dataclass(frozen=True)
class Observation:
    """One observation of a streams document.

    ``value`` is the element's text (a condition's message); ``condition`` is set for a
    condition's entries, None for events and samples.
    """

    device: str
    data_item_id: str
    sequence: int
    timestamp: str
    tag: str  # the element's name: Execution, PartCount, Fault, ...
    value: str
    condition: Condition | None = None


@dataclass(frozen=True)
class Streams:
    """A current or sample answer (MTConnectStreams), observations in document order."""

    header: Header
    observations: tuple[Observation, ...]


def _parser() -> etree.XMLParser:
    # A new parser per document: an lxml parser must not be used by two threads at once.
    return etree.XMLParser(
        resolve_entities=False,
        no_network=True,
        load_dtd=False,
        dtd_validation=False,
        huge_tree=False,
        remove_comments=True,
        remove_pis=True,
    )


def _local(element: etree._Element) -> str:
    tag = element.tag
    if not isinstance(tag, str):  # a comment or processing instruction left in
        return ""
    return tag.rsplit("}", 1)[-1]


def _root(data: bytes) -> etree._Element:
    if not isinstance(data, bytes | bytearray | memoryview):
        raise RemoteProtocolError("MTConnect document: expected bytes")
    data = bytes(data)
    if len(data) > MAX_DOCUMENT:
        raise RemoteProtocolError(f"MTConnect document of {len(data)} bytes is too large")
    if b"<!DOCTYPE" in data or b"<!ENTITY" in data:
        raise RemoteProtocolError("MTConnect document declares a DOCTYPE or an entity: refused")
    try:
        root = etree.fromstring(data, parser=_parser())
    except etree.XMLSyntaxError as exc:
        raise RemoteProtocolError(f"MTConnect document is not well-formed XML: {exc}") from None
    except ValueError as exc:  # e.g. an encoding lxml refuses
        raise RemoteProtocolError(f"MTConnect document cannot be read: {exc}") from None
    if root is None:
        raise RemoteProtocolError("MTConnect document is empty")
    return root


def _text(element: etree._Element) -> str:
    return "".join(t for t in element.itertext() if isinstance(t, str))


def _int(element: etree._Element, name: str, *, default: int | None = None) -> int:
    text = element.get(name)
    if text is None:
        if default is not None:
            return default
        raise RemoteProtocolError(f"MTConnect {_local(element)} lacks {name}")
    try:
        value = int(text)
    except ValueError:
        raise RemoteProtocolError(
            f"MTConnect {_local(element)} {name}={text[:40]!r} is not a number"
        ) from None
    if value < 0:
        raise RemoteProtocolError(f"MTConnect {_local(element)} {name}={value} is negative")
    return value


def _header(root: etree._Element, *, streams: bool) -> Header:
    header = next((e for e in root if _local(e) == "Header"), None)
    if header is None:
        raise RemoteProtocolError(f"MTConnect {_local(root)} has no Header")
    return Header(
        instance_id=_int(header, "instanceId"),
        version=header.get("version", ""),
        sender=header.get("sender", ""),
        first_sequence=_int(header, "firstSequence") if streams else 0,
        last_sequence=_int(header, "lastSequence") if streams else 0,
        next_sequence=_int(header, "nextSequence") if streams else 0,
    )


def _refusal(root: etree._Element) -> AgentRefused:
    codes, texts = [], []
    for element in root.iter():
        code = element.get("errorCode") if isinstance(element.tag, str) else None
        if code:
            codes.append(code)
            text = " ".join(_text(element).split())
            if text:
                texts.append(text)
    return AgentRefused(tuple(codes) or ("UNKNOWN",), "; ".join(texts)[:500])


def _streams(root: etree._Element) -> Streams:
    header = _header(root, streams=True)
    observations: list[Observation] = []
    for streams in (e for e in root if _local(e) == "Streams"):
        for device_stream in streams:
            if _local(device_stream) != "DeviceStream":
                continue
            device = device_stream.get("name", "")
            for element in device_stream.iter():
                if element.get("dataItemId") is None or not isinstance(element.tag, str):
                    continue
                observations.append(_observation(element, device))
    return Streams(header, tuple(observations))


def _observation(element: etree._Element, device: str) -> Observation:
    tag = _local(element)
    parent = element.getparent()
    in_condition = parent is not None and _local(parent) == "Condition"
    condition = None
    if in_condition:
        if tag not in _CONDITION_LEVELS:
            raise RemoteProtocolError(f"MTConnect condition level {tag[:40]!r} is not known")
        condition = Condition(
            level=tag,
            native_code=element.get("nativeCode", ""),
            native_severity=element.get("nativeSeverity", ""),
            qualifier=element.get("qualifier", ""),
            condition_id=element.get("conditionId", ""),
        )
    return Observation(
        device=device,
        data_item_id=element.get("dataItemId", ""),
        sequence=_int(element, "sequence"),
        timestamp=element.get("timestamp", ""),
        tag=tag,
        value=" ".join(_text(element).split()),
        condition=condition,
    )


def _devices(root: etree._Element) -> Devices:
    header = _header(root, streams=False)
    devices: list[Device] = []
    for container in (e for e in root if _local(e) == "Devices"):
        for device in container:
            if _local(device) not in ("Device", "Agent"):
                continue
            name = device.get("name", "")
            items = []
            for element in device.iter():
                if _local(element) != "DataItem":
                    continue
                ident, kind = element.get("id"), element.get("type")
                if not ident or not kind:
                    raise RemoteProtocolError("MTConnect DataItem lacks its id or type")
                items.append(
                    DataItem(
                        id=ident,
                        type=kind,
                        category=element.get("category", ""),
                        device=name,
                        name=element.get("name", ""),
                        sub_type=element.get("subType", ""),
                    )
                )
            devices.append(Device(name=name, uuid=device.get("uuid", ""), items=tuple(items)))
    return Devices(header, tuple(devices))


def parse_document(data: bytes) -> Devices | Streams:
    """A probe or streams document; :class:`AgentRefused` for an error document,
    :class:`~opendnc.errors.RemoteProtocolError` for anything else."""
    root = _root(data)
    kind = _local(root)
    if kind == "MTConnectError":
        raise _refusal(root)
    if kind == "MTConnectStreams":
        return _streams(root)
    if kind == "MTConnectDevices":
        return _devices(root)
    raise RemoteProtocolError(f"not an MTConnect document: root element {kind[:40]!r}")


def parse_streams(data: bytes) -> Streams:
    """A current or sample answer (raises as :func:`parse_document`)."""
    document = parse_document(data)
    if not isinstance(document, Streams):
        raise RemoteProtocolError("expected an MTConnectStreams document, got MTConnectDevices")
    return document


def parse_devices(data: bytes) -> Devices:
    """A probe answer (raises as :func:`parse_document`)."""
    document = parse_document(data)
    if not isinstance(document, Devices):
        raise RemoteProtocolError("expected an MTConnectDevices document, got MTConnectStreams")
    return document
