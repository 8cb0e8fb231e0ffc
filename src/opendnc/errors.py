"""The exception tree of opendnc.

Every error this package raises on purpose derives from :class:`DncError`::

    DncError
    ├── TransportError            cannot connect, port vanished, I/O failed
    │   ├── TransportTimeout      no answer in time
    │   └── PeerClosed            the other side closed the link
    ├── ProtocolError
    │   ├── LocalProtocolError    the caller misused an engine (a bug on our side)
    │   └── RemoteProtocolError   the peer sent malformed or unexpected bytes
    │       └── ChecksumError     a block check failed
    ├── ControlRefused            a well-formed "no" from the control (LSV2 T_ER/T_BD, ...)
    ├── SafetyLockError           a machine-changing action without the explicit opt-in
    ├── TransferError             a file transfer failed after its retries
    ├── InputError                a local file or argument is unusable
    └── ProgramTextError          a text program holds bytes no NC program holds

``OSError``, ``serial.SerialException`` and asyncio timeouts are translated into this tree
at the transport boundary, so callers only ever catch ``DncError`` subclasses.
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from opendnc.nctext import TextProblem


class DncError(Exception):
    """Base of everything opendnc raises on purpose."""


class TransportError(DncError):
    """The link could not be opened, or failed while in use."""


class TransportTimeout(TransportError):
    """No data arrived within the allowed time."""


class PeerClosed(TransportError):
    """The peer closed the connection."""


class ProtocolError(DncError):
    """Bytes on the wire do not follow the protocol."""


class LocalProtocolError(ProtocolError):
    """The caller asked an engine for something the protocol does not allow now."""


class RemoteProtocolError(ProtocolError):
    """The peer sent malformed, truncated or unexpected data."""


class ChecksumError(RemoteProtocolError):
    """A block check character, checksum or CRC did not match."""


class ControlRefused(DncError):
    """The control answered a request with a well-formed refusal.

    ``code`` is the protocol's error number and ``text`` its readable meaning.
    """

    def __init__(self, code: int, text: str = "", *, context: str = "") -> None:
        self.code = code
        self.text = text
        self.context = context
        detail = f"{text} ({code})" if text else f"error {code}"
        super().__init__(f"{context}: {detail}" if context else detail)


class SafetyLockError(DncError):
    """A machine-changing action was requested while safe mode is on."""

    def __init__(self, action: str) -> None:
        self.action = action
        super().__init__(
            f"{action} can change machine behaviour and is locked: "
            "turn safe mode off explicitly (safe_mode=False / --unsafe) to allow it"
        )


class TransferError(DncError):
    """A file transfer did not complete (retries exhausted, cancelled, aborted)."""


class InputError(DncError):
    """A local file, path or argument cannot be used as given."""


class UsageError(DncError):
    """A call the API does not allow in that order or combination: a mistake in the calling
    code (a decision confirmed twice, a person's override asked of the server), not bad input
    from a user or a wire."""


class ProgramTextError(DncError):
    """A program that should be NC text holds a byte no NC program holds.

    Raised for a received program (damage that the transfer's own check missed) and for a
    program about to be sent. ``problem`` says where: block (line), column, byte offset.
    """

    def __init__(self, problem: TextProblem, *, what: str = "program", action: str = "") -> None:
        self.problem = problem
        self.what = what
        detail = f"{what}: {problem.describe()} is not NC program text"
        super().__init__(f"{detail}; {action}" if action else detail)


def os_reason(exc: OSError) -> str:
    """The operating system's words for ``exc``, without Python's decoration.

    asyncio words a refused connection "Connect call failed ('127.0.0.1', 5051)" and a socket
    call "[Errno 111] Connection refused"; a person reading a card or a log wants "connection
    refused". Errors without a number (a bad host name, say) keep their own text.
    """
    if exc.errno is not None:
        try:
            text = os.strerror(exc.errno)
        except ValueError:
            text = ""
        if text and not text.startswith("Unknown error"):
            return text[0].lower() + text[1:]
    text = exc.strerror or str(exc) or type(exc).__name__
    return text[0].lower() + text[1:]
