"""An independent Sparkplug B reader for the tests: not the package that encodes (pysparkplug).

No installable Tahu package fits beside pysparkplug (the ones on PyPI pin protobuf 3 or 4,
pysparkplug needs 5 or later), so the payload's schema is declared here from the Sparkplug B
specification's facts: the field numbers and wire types of Tahu's ``sparkplug_b.proto``
(Payload: timestamp 1, metrics 2, seq 3; Metric: name 1, alias 2, timestamp 3, datatype 4,
is_null 7, int_value 10, long_value 11, float_value 12, double_value 13, boolean_value 14,
string_value 15, bytes_value 16) and its datatype numbers, with protobuf's own descriptor
classes in a pool of our own. :class:`Host` is a small Sparkplug host application: it follows
births, deaths and data per edge node and checks ``seq``, ``bdSeq`` and aliases as it goes.
"""

from __future__ import annotations

import json
import threading
from dataclasses import dataclass, field
from typing import Any

from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

# Sparkplug B datatypes (the specification's table of data types).
INT8, INT16, INT32, INT64 = 1, 2, 3, 4
UINT8, UINT16, UINT32, UINT64 = 5, 6, 7, 8
FLOAT, DOUBLE, BOOLEAN, STRING = 9, 10, 11, 12

_T = descriptor_pb2.FieldDescriptorProto


def _schema() -> tuple[Any, Any]:
    proto = descriptor_pb2.FileDescriptorProto(
        name="opendnc_tests/spb_reader.proto", package="opendnc_tests.spb", syntax="proto2"
    )
    payload = proto.message_type.add(name="Payload")
    metric = payload.nested_type.add(name="Metric")
    optional, repeated = _T.LABEL_OPTIONAL, _T.LABEL_REPEATED
    for name, number, kind in (
        ("name", 1, _T.TYPE_STRING),
        ("alias", 2, _T.TYPE_UINT64),
        ("timestamp", 3, _T.TYPE_UINT64),
        ("datatype", 4, _T.TYPE_UINT32),
        ("is_historical", 5, _T.TYPE_BOOL),
        ("is_transient", 6, _T.TYPE_BOOL),
        ("is_null", 7, _T.TYPE_BOOL),
        ("int_value", 10, _T.TYPE_UINT32),
        ("long_value", 11, _T.TYPE_UINT64),
        ("float_value", 12, _T.TYPE_FLOAT),
        ("double_value", 13, _T.TYPE_DOUBLE),
        ("boolean_value", 14, _T.TYPE_BOOL),
        ("string_value", 15, _T.TYPE_STRING),
        ("bytes_value", 16, _T.TYPE_BYTES),
    ):
        metric.field.add(name=name, number=number, type=kind, label=optional)
    payload.field.add(name="timestamp", number=1, type=_T.TYPE_UINT64, label=optional)
    payload.field.add(
        name="metrics",
        number=2,
        type=_T.TYPE_MESSAGE,
        label=repeated,
        type_name=".opendnc_tests.spb.Payload.Metric",
    )
    payload.field.add(name="seq", number=3, type=_T.TYPE_UINT64, label=optional)
    payload.field.add(name="uuid", number=4, type=_T.TYPE_STRING, label=optional)
    payload.field.add(name="body", number=5, type=_T.TYPE_BYTES, label=optional)
    pool = descriptor_pool.DescriptorPool()  # our own: pysparkplug's lives in the default one
    pool.Add(proto)
    payload_class = message_factory.GetMessageClass(
        pool.FindMessageTypeByName("opendnc_tests.spb.Payload")
    )
    return payload_class, payload_class.Metric


PayloadMessage, MetricMessage = _schema()

_SIGNED_BITS = {INT8: 8, INT16: 16, INT32: 32, INT64: 64}


def _value(m: Any, datatype: int | None) -> Any:
    """The metric's value by the field that is set, signed by its datatype where it has one."""
    if m.is_null:
        return None
    for name in ("int_value", "long_value"):
        if m.HasField(name):
            raw = getattr(m, name)
            bits = _SIGNED_BITS.get(datatype or 0)
            # Signed integers travel as their two's complement in an unsigned field.
            if bits is not None and raw >= 1 << (bits - 1):
                raw -= 1 << bits
            return raw
    for name in ("float_value", "double_value", "boolean_value", "string_value", "bytes_value"):
        if m.HasField(name):
            return getattr(m, name)
    return None


@dataclass(frozen=True)
class Metric:
    name: str | None
    alias: int | None
    datatype: int | None
    value: Any
    is_null: bool
    timestamp: int | None


@dataclass(frozen=True)
class Payload:
    timestamp: int | None
    seq: int | None
    metrics: tuple[Metric, ...]

    def by_name(self) -> dict[str, Metric]:
        return {m.name: m for m in self.metrics if m.name is not None}


def decode(raw: bytes, datatypes: dict[int, int] | None = None) -> Payload:
    """A Sparkplug B payload; ``datatypes`` (alias -> datatype) signs DDATA's aliased values."""
    message = PayloadMessage.FromString(raw)
    metrics = []
    for m in message.metrics:
        alias = m.alias if m.HasField("alias") else None
        datatype = m.datatype if m.HasField("datatype") else None
        if datatype is None and alias is not None and datatypes:
            datatype = datatypes.get(alias)
        metrics.append(
            Metric(
                name=m.name if m.HasField("name") else None,
                alias=alias,
                datatype=datatype,
                value=_value(m, datatype),
                is_null=m.is_null,
                timestamp=m.timestamp if m.HasField("timestamp") else None,
            )
        )
    return Payload(
        timestamp=message.timestamp if message.HasField("timestamp") else None,
        seq=message.seq if message.HasField("seq") else None,
        metrics=tuple(metrics),
    )


def encode_command(metrics: dict[str, bool], timestamp: int) -> bytes:
    """An NCMD payload (Boolean metrics by name), as a host sends it."""
    message = PayloadMessage(timestamp=timestamp)
    for name, value in metrics.items():
        message.metrics.add(name=name, datatype=BOOLEAN, boolean_value=value, timestamp=timestamp)
    return bytes(message.SerializeToString())


def state_payload(online: bool, timestamp: int) -> bytes:
    """A primary host's STATE (Sparkplug B 3.0: JSON)."""
    return json.dumps({"online": online, "timestamp": timestamp}).encode()


_KINDS = {"NBIRTH", "NDEATH", "DBIRTH", "DDEATH", "NDATA", "DDATA", "NCMD", "DCMD"}


class SparkplugViolation(AssertionError):
    """A message broke a rule of Sparkplug B."""


@dataclass
class Device:
    names: dict[int, str] = field(default_factory=dict)  # alias -> name
    datatypes: dict[int, int] = field(default_factory=dict)  # alias -> datatype
    values: dict[str, Any] = field(default_factory=dict)
    alive: bool = False


@dataclass
class Node:
    bd_seq: int | None = None  # of its current birth
    seq: int | None = None  # of its last message
    alive: bool = False
    devices: dict[str, Device] = field(default_factory=dict)
    births: int = 0


@dataclass(frozen=True)
class Seen:
    """One message as the host took it."""

    kind: str
    node: str
    device: str | None
    payload: Payload


class Host:
    """A Sparkplug host application over decoded messages: it keeps each node's and device's
    state and raises :class:`SparkplugViolation` for a message out of order."""

    def __init__(self, group: str) -> None:
        self.group = group
        self.nodes: dict[str, Node] = {}
        self.seen: list[Seen] = []
        self.lock = threading.Lock()

    def take(self, topic: str, raw: bytes) -> None:
        parts = topic.split("/")
        if len(parts) < 4 or parts[0] != "spBv1.0" or parts[1] != self.group:
            return
        kind, node_id = parts[2], parts[3]
        if kind not in _KINDS:
            return  # not a Sparkplug message (a test's marker)
        device_id = parts[4] if len(parts) > 4 else None
        with self.lock:
            node = self.nodes.setdefault(node_id, Node())
            datatypes = None
            if device_id is not None and device_id in node.devices:
                datatypes = node.devices[device_id].datatypes
            payload = decode(raw, datatypes)
            self.seen.append(Seen(kind, node_id, device_id, payload))
            getattr(self, f"_{kind.lower()}")(node, node_id, device_id, payload)

    def _check_seq(self, node: Node, payload: Payload, what: str) -> None:
        if not node.alive:
            raise SparkplugViolation(f"{what} from a node that is not born")
        expected = (node.seq + 1) % 256 if node.seq is not None else 0
        if payload.seq != expected:
            raise SparkplugViolation(f"{what}: seq {payload.seq}, expected {expected}")
        node.seq = payload.seq

    def _nbirth(self, node: Node, _id: str, _dev: str | None, payload: Payload) -> None:
        metrics = payload.by_name()
        if payload.seq != 0:
            raise SparkplugViolation(f"NBIRTH with seq {payload.seq}")
        if "bdSeq" not in metrics or "Node Control/Rebirth" not in metrics:
            raise SparkplugViolation(f"NBIRTH without bdSeq or rebirth: {sorted(metrics)}")
        node.bd_seq = metrics["bdSeq"].value
        node.seq = 0
        node.alive = True
        node.births += 1
        for device in node.devices.values():
            device.alive = False  # a new birth: every device is born again

    def _ndeath(self, node: Node, _id: str, _dev: str | None, payload: Payload) -> None:
        bd_seq = payload.by_name()["bdSeq"].value
        if bd_seq != node.bd_seq:
            return  # a late death of an earlier session: the host ignores it
        node.alive = False
        for device in node.devices.values():
            device.alive = False

    def _dbirth(self, node: Node, _id: str, device_id: str | None, payload: Payload) -> None:
        self._check_seq(node, payload, f"DBIRTH {device_id}")
        assert device_id is not None
        device = Device(alive=True)
        for m in payload.metrics:
            if m.name is None or m.alias is None or m.datatype is None:
                raise SparkplugViolation(f"DBIRTH {device_id}: a metric without name/alias/type")
            device.names[m.alias] = m.name
            device.datatypes[m.alias] = m.datatype
            device.values[m.name] = m.value
        node.devices[device_id] = device

    def _ddata(self, node: Node, _id: str, device_id: str | None, payload: Payload) -> None:
        self._check_seq(node, payload, f"DDATA {device_id}")
        device = node.devices.get(device_id or "")
        if device is None or not device.alive:
            raise SparkplugViolation(f"DDATA for {device_id}, which is not born")
        for m in payload.metrics:
            if m.alias not in device.names:
                raise SparkplugViolation(f"DDATA {device_id}: unknown alias {m.alias}")
            device.values[device.names[m.alias]] = m.value

    def _ddeath(self, node: Node, _id: str, device_id: str | None, payload: Payload) -> None:
        self._check_seq(node, payload, f"DDEATH {device_id}")
        device = node.devices.get(device_id or "")
        if device is None or not device.alive:
            raise SparkplugViolation(f"DDEATH for {device_id}, which is not born")
        device.alive = False

    def _ndata(self, node: Node, _id: str, _dev: str | None, payload: Payload) -> None:
        self._check_seq(node, payload, "NDATA")

    def _ncmd(self, *_args: object) -> None:
        return None  # the host's own commands

    def _dcmd(self, *_args: object) -> None:
        return None

    # -- reading ----------------------------------------------------------------------------

    def kinds(self, node: str | None = None) -> list[str]:
        """The message kinds seen, in order (``DBIRTH:mill-1`` for a device's)."""
        with self.lock:
            return [
                f"{s.kind}:{s.device}" if s.device else s.kind
                for s in self.seen
                if node is None or s.node == node
            ]

    def of(self, kind: str, node: str | None = None, device: str | None = None) -> list[Seen]:
        with self.lock:
            return [
                s
                for s in self.seen
                if s.kind == kind
                and (node is None or s.node == node)
                and (device is None or s.device == device)
            ]

    def device(self, node: str, device: str) -> Device | None:
        with self.lock:
            found = self.nodes.get(node)
            return found.devices.get(device) if found else None
