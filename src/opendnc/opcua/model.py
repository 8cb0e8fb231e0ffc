"""The parts of the OPC 40501-1 machine-tool model that opendnc reads, as plain data.

The companion specification's nodeset files are not shipped with asyncua nor with any package
our registries offer as Python, so neither side loads them: the client finds nodes by their
browse names (the ``Name`` part only, whatever namespace index a server gives them), and the
virtual server builds the same names as plain objects and variables
(docs/opcua-input.md#the-address-space). Enumeration values are the integers on the wire
(docs/opcua-input.md#enumerations).
"""

from __future__ import annotations

from enum import IntEnum

__all__ = [
    "MACHINERY_NS",
    "MACHINES_FOLDER",
    "MACHINE_TOOL_NS",
    "ChannelMode",
    "ChannelState",
    "MachineOperationMode",
    "Paths",
    "ProgramState",
    "SignalColor",
]

MACHINE_TOOL_NS = "http://opcfoundation.org/UA/MachineTool/"
"""The namespace URI of OPC 40501-1 (the machine objects' browse names are in it)."""

MACHINERY_NS = "http://opcfoundation.org/UA/Machinery/"
"""The namespace URI of OPC 40001-1 (Machinery), whose ``Machines`` folder holds machines."""

MACHINES_FOLDER = "Machines"
"""The folder under ``Objects`` where umati servers list their machines (a setting)."""


class ChannelState(IntEnum):
    """ChannelState of a channel (OPC 40501-1 enumeration)."""

    ACTIVE = 0
    INTERRUPTED = 1
    RESET = 2


class ChannelMode(IntEnum):
    """ChannelMode of a channel (OPC 40501-1 enumeration)."""

    AUTOMATIC = 0
    MDA_MDI = 1
    JOG_MANUAL = 2
    JOG_INCREMENT = 3
    TEACHING_HANDLE = 4
    REMOTE = 5
    REFERENCE = 6
    OTHER = 7


class MachineOperationMode(IntEnum):
    """OperationMode of ``Monitoring/MachineTool`` (OPC 40501-1 enumeration)."""

    MANUAL = 0
    AUTOMATIC = 1
    SETUP = 2
    AUTO_WITH_MANUAL_INTERVENTION = 3
    SERVICE = 4
    OTHER = 5


class SignalColor(IntEnum):
    """SignalColor of a stacklight element (OPC 10031-4, IA)."""

    OFF = 0
    RED = 1
    GREEN = 2
    BLUE = 3
    YELLOW = 4
    PURPLE = 5
    CYAN = 6
    WHITE = 7


class ProgramState:
    """The state names of the production program state machine (its ``CurrentState`` text)."""

    INITIALIZING = "Initializing"
    RUNNING = "Running"
    ENDED = "Ended"
    INTERRUPTED = "Interrupted"
    ABORTED = "Aborted"


class Paths:
    """Browse paths below a machine object, as tuples of browse names."""

    MONITORING = ("Monitoring",)
    OPERATION_MODE = ("Monitoring", "MachineTool", "OperationMode")
    STACKLIGHT = ("Monitoring", "Stacklight")
    PROGRAM_NAME = ("Production", "ActiveProgram", "Name")
    PROGRAM_NUMBER = ("Production", "ActiveProgram", "NumberInList")
    PROGRAM_STATE = ("Production", "ActiveProgram", "State", "CurrentState")
    PARTS = ("Production", "Statistics", "PartsProducedInLifetime")
    MESSAGES = ("Notification", "Messages")
    CHANNEL_STATE = "ChannelState"  # children of a channel (a monitored element)
    CHANNEL_MODE = "ChannelMode"
    FEED_OVERRIDE = "FeedOverride"
    # children of a stacklight element
    SIGNAL_ON = "SignalOn"
    SIGNAL_COLOR = "SignalColor"
