"""The configuration schema of an ``opcua`` machine (its own module: the connector reads it,
and the kind's spec imports the connector)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

from opendnc.opcua.model import MACHINE_TOOL_NS, MACHINES_FOLDER
from opendnc.server.kinds.base import MachineBase

__all__ = ["SECURITY_MODES", "SECURITY_POLICIES", "OpcuaMachine"]

SECURITY_POLICIES = ("None", "Basic256Sha256")
SECURITY_MODES = ("Sign", "SignAndEncrypt")


@dataclass(frozen=True, kw_only=True)
class OpcuaMachine(MachineBase):
    """A machine tool read through an OPC UA server that models it after OPC 40501-1.

    Which machine object is read: ``machine_node`` (a node id) when set; otherwise the child
    of ``browse_root`` whose browse name is ``machine``, or the first child there that looks
    like a machine tool (it has ``Monitoring`` and ``Production``) when ``machine`` is empty
    (docs/opcua-input.md#settings)."""

    kind: ClassVar[str] = "opcua"

    endpoint: str  # opc.tcp://host:port[/path]
    machine: str = ""  # the machine object's browse name under browse_root
    browse_root: str = f"Objects/{MACHINES_FOLDER}"  # browse names from the Root folder
    machine_node: str = ""  # "ns=3;i=5001" or "nsu=URI;s=...": skips the browse
    namespace: str = MACHINE_TOOL_NS  # looked up for machine_node's nsu= form only
    channel: str = ""  # the channel's browse name under Monitoring; "": the first
    security_policy: str = "None"  # or Basic256Sha256
    security_mode: str = "SignAndEncrypt"  # or Sign (with Basic256Sha256)
    certificate: str = ""  # our certificate (DER or PEM) for Basic256Sha256
    private_key: str = ""  # its private key (PEM)
    server_certificate: str = ""  # the server's certificate; "": taken from its endpoints
    application_uri: str = "urn:opendnc:client"  # must match the certificate's URI
    user: str = ""
    password: str = field(default="", repr=False)
    # seconds between the server's notifications: a step's changes come in one (measured:
    # docs/opcua-input.md#cost-per-machine)
    publishing_interval: float = 0.25
    request_timeout: float = 4.0  # seconds a request may take
    # seconds between two reads that the session is alive (a closed socket is seen at once;
    # this finds a silent one): a read a second was half of a lone machine's requests
    watchdog: float = 5.0
