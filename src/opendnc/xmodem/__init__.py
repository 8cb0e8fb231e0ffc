"""XModem (checksum, CRC-16, 1K) as sans-IO engines, with blocking and asyncio drivers.

* :mod:`~opendnc.xmodem.framing` -- control bytes, checksum/CRC, block encode/decode.
* :mod:`~opendnc.xmodem.sender` / :mod:`~opendnc.xmodem.receiver` -- the state machines.
* :mod:`~opendnc.xmodem.driver` -- ``send``/``receive`` over a ByteStream, asyncio twins.
* :mod:`~opendnc.xmodem.haas` -- Haas program conventions (EOB, SUB padding, O-number).
* :mod:`~opendnc.xmodem.files` -- file transfers with temp file + rename.
"""

from opendnc.xmodem.events import (
    BlockDone,
    Completed,
    DataReceived,
    Duplicate,
    EotAnswer,
    Event,
    Failed,
    FallbackToSmall,
    Retry,
    Started,
    Timer,
)
from opendnc.xmodem.framing import Mode
from opendnc.xmodem.receiver import ReceiverConfig, XmodemReceiver
from opendnc.xmodem.sender import SenderConfig, XmodemSender

__all__ = [
    "BlockDone",
    "Completed",
    "DataReceived",
    "Duplicate",
    "EotAnswer",
    "Event",
    "Failed",
    "FallbackToSmall",
    "Mode",
    "ReceiverConfig",
    "Retry",
    "SenderConfig",
    "Started",
    "Timer",
    "XmodemReceiver",
    "XmodemSender",
]
