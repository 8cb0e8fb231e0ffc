"""Heidenhain LSV2: sans-IO codec and engine, plus blocking and asyncio clients.

Layers, bottom up:

* :mod:`~opendnc.lsv2.framing` - TCP telegram framer and the RS-232 DLE/BCC frame codec
* :mod:`~opendnc.lsv2.messages` - typed telegrams (both directions) and the codec registry
* :mod:`~opendnc.lsv2.payloads`, :mod:`~opendnc.lsv2.runinfo` - typed data layouts
* :mod:`~opendnc.lsv2.connection` - the sans-IO engine used by client and simulator
"""

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

__all__ = [
    "CcCommand",
    "ErrorCode",
    "ExecutionMode",
    "Family",
    "Frame",
    "KeyCode",
    "Login",
    "Lsv2Connection",
    "MemoryType",
    "OldKeyCode",
    "ProgramState",
    "Role",
    "RunInfo",
    "SerialFramer",
    "State",
    "TelegramFramer",
    "TransferMode",
    "detect_family",
    "error_text",
]
