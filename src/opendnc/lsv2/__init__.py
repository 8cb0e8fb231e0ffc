"""Heidenhain LSV2: sans-IO codec and engine, plus blocking and asyncio clients.

Layers, bottom up:

* :mod:`~opendnc.lsv2.framing` - TCP telegram framer and the RS-232 DLE/BCC frame codec
* :mod:`~opendnc.lsv2.messages` - typed telegrams (both directions) and the codec registry
* :mod:`~opendnc.lsv2.payloads`, :mod:`~opendnc.lsv2.runinfo` - typed data layouts
* :mod:`~opendnc.lsv2.connection` - the sans-IO engine used by client and simulator
* :mod:`~opendnc.lsv2.ops` - every multi-telegram procedure, written once as a generator
* :mod:`~opendnc.lsv2.drive` - blocking and asyncio drivers that run those generators
* :class:`Client` (blocking) and :class:`AsyncClient` (asyncio) - the public facades

>>> from opendnc.lsv2 import Client
>>> # with Client("192.168.56.101") as tnc: print(tnc.versions, tnc.list_dir("TNC:/"))
"""

from opendnc.lsv2.aio import AsyncClient
from opendnc.lsv2.client import Client
from opendnc.lsv2.connection import Lsv2Connection, Role, State
from opendnc.lsv2.constants import (
    CcCommand,
    ErrorCode,
    ExecutionMode,
    Family,
    KeyCode,
    Login,
    MemoryType,
    OldKeyCode,
    ProgramState,
    RunInfo,
    TransferMode,
    detect_family,
    error_text,
)
from opendnc.lsv2.framing import Frame, SerialFramer, TelegramFramer
from opendnc.lsv2.ops import FileInfo, ScopeRecording, SystemInfo, Uptimes
from opendnc.lsv2.payloads import DirectoryInfo, FileEntry, SystemParameters, Versions
from opendnc.lsv2.plc import PlcOperand, parse_operand
from opendnc.lsv2.runinfo import (
    AxesPositions,
    NcError,
    Overrides,
    SelectedProgram,
    ToolInfo,
)
from opendnc.lsv2.tables import Table, parse_table

__all__ = [
    "AsyncClient",
    "AxesPositions",
    "CcCommand",
    "Client",
    "DirectoryInfo",
    "ErrorCode",
    "ExecutionMode",
    "Family",
    "FileEntry",
    "FileInfo",
    "Frame",
    "KeyCode",
    "Login",
    "Lsv2Connection",
    "MemoryType",
    "NcError",
    "OldKeyCode",
    "Overrides",
    "PlcOperand",
    "ProgramState",
    "Role",
    "RunInfo",
    "ScopeRecording",
    "SelectedProgram",
    "SerialFramer",
    "State",
    "SystemInfo",
    "SystemParameters",
    "Table",
    "TelegramFramer",
    "ToolInfo",
    "TransferMode",
    "Uptimes",
    "Versions",
    "detect_family",
    "error_text",
    "parse_operand",
    "parse_table",
]
