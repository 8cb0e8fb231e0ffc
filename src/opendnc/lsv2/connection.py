"""The sans-IO LSV2 engine: bytes in, typed messages out, for either end of the link.

:class:`Lsv2Connection` does no I/O and reads no clock. A driver feeds it received bytes
(``receive_data``), asks for complete messages (``next_event``) and writes what ``send``
returns. The same class serves the client (:attr:`Role.CLIENT`) and the simulator
(:attr:`Role.SERVER`), so both agree on framing, buffer size and session flags.

What the engine tracks:

* **request/answer turn-taking** (client role): after a request it expects exactly one answer;
  a telegram arriving when nothing was asked raises :class:`RemoteProtocolError`. ``T_FD``
  expects an answer only after secure file send (``C_CC`` 19) was accepted; a bare ``T_BD``
  (abort / stop scope) never does.
* **unsolicited ``M_CC``** (client role): queued, never mistaken for an answer; read them with
  :meth:`Lsv2Connection.next_notice`.
* **buffer size**: 256 bytes until a ``C_CC`` 3-7 is acknowledged with ``T_OK``, then the new
  size, for both directions. ``send`` refuses telegrams that do not fit.
* **secure file send**: set once ``C_CC`` 19 is acknowledged.

>>> from opendnc.lsv2.messages import Login
>>> client = Lsv2Connection(Role.CLIENT)
>>> client.send(Login("INSPECT"))
b'\\x00\\x00\\x00\\x08A_LGINSPECT\\x00'
>>> client.receive_data(b"\\x00\\x00\\x00\\x00T_OK")
>>> client.next_event()
Ok()
"""

from __future__ import annotations

import enum
from collections import deque
from collections.abc import Callable
from typing import Literal

from opendnc.errors import LocalProtocolError, PeerClosed, RemoteProtocolError
from opendnc.lsv2.constants import BUFFER_SIZES, DEFAULT_BUFFER_SIZE, CcCommand
from opendnc.lsv2.framing import DEFAULT_MAX_PAYLOAD, HEADER, HEADER_SIZE, Frame, TelegramFramer
from opendnc.lsv2.messages import (
    BlockDefect,
    CommandDone,
    FileDone,
    Message,
    Ok,
    SystemCommand,
    decode,
)

__all__ = [
    "BytesHook",
    "Direction",
    "Lsv2Connection",
    "Role",
    "State",
    "TraceHook",
    "UndecodableTelegram",
]

# Telegrams without a payload have the same 8 wire bytes every time; T_OK alone is sent once
# per file block, so it is worth not packing it again (they fit any buffer size).
_FIXED_WIRE: dict[type[Message], bytes] = {
    cls: HEADER.pack(0, cls.MNEMONIC_BYTES) for cls in (Ok, FileDone)
}

Direction = Literal["send", "recv"]
TraceHook = Callable[[Direction, Message], None]
BytesHook = Callable[[Direction, bytes], None]


class UndecodableTelegram(RemoteProtocolError):
    """A complete telegram arrived whose payload does not decode; framing is still intact.

    Unlike other :class:`RemoteProtocolError` raised by :meth:`Lsv2Connection.next_event`
    (the framer lost sync: an absurd length, a name that is no name), the link is still
    usable: a server refuses this one telegram and carries on.
    """

    def __init__(self, frame: Frame, problem: RemoteProtocolError) -> None:
        super().__init__(str(problem))
        self.frame = frame


def _decode(frame: Frame) -> Message:
    try:
        return decode(frame)
    except RemoteProtocolError as exc:
        raise UndecodableTelegram(frame, exc) from exc


class Role(enum.Enum):
    """Which end of the link the engine plays."""

    CLIENT = "client"
    SERVER = "server"


class State(enum.Enum):
    """Client turn-taking state."""

    IDLE = "idle"
    WAITING = "waiting"


class Lsv2Connection:
    """Sans-IO LSV2 engine for one TCP session (see the module docstring)."""

    def __init__(
        self,
        role: Role,
        *,
        max_payload: int = DEFAULT_MAX_PAYLOAD,
        on_message: TraceHook | None = None,
        on_bytes: BytesHook | None = None,
    ) -> None:
        self.role = role
        self.state = State.IDLE
        self.buffer_size = DEFAULT_BUFFER_SIZE
        """Largest telegram (header included) either side may send now."""
        self.secure_send = False
        """True once ``C_CC`` 19 was acknowledged: ``T_FD`` then gets an answer."""
        self.on_message = on_message
        self.on_bytes = on_bytes
        """Called with the raw wire bytes of every send and receive (hex traces)."""
        self.last_frame: Frame | None = None
        """The most recent raw frame received (its wire size and bytes, for traces)."""
        self._framer = TelegramFramer(max_payload)
        self._eof = False
        self._pending_cc: int | None = None
        self._notices: deque[CommandDone] = deque()

    # -- sending -----------------------------------------------------------------------------

    def send(self, message: Message) -> bytes:
        """Return the wire bytes of ``message`` (header and payload in one string)."""
        wire = _FIXED_WIRE.get(type(message))
        if wire is None:
            payload = message.to_payload()
            size = HEADER_SIZE + len(payload)
            if size > self.buffer_size:
                raise LocalProtocolError(
                    f"{message.mnemonic} of {size} bytes exceeds the buffer of {self.buffer_size}"
                )
            name = message.MNEMONIC_BYTES or message.mnemonic.encode("ascii")
            wire = HEADER.pack(len(payload), name) + payload
        if self.role is Role.CLIENT:
            self._client_sent(message)
        else:
            self._server_sent(message)
        if self.on_message is not None:
            self.on_message("send", message)
        if self.on_bytes is not None:
            self.on_bytes("send", wire)
        return wire

    def expects_reply(self, message: Message) -> bool:
        """Whether the peer answers ``message`` when the client sends it."""
        if isinstance(message, FileDone):
            return self.secure_send
        return not isinstance(message, BlockDefect)

    def _client_sent(self, message: Message) -> None:
        if self.state is State.WAITING:
            raise LocalProtocolError(f"cannot send {message.mnemonic}: still waiting for an answer")
        if self.expects_reply(message):
            self.state = State.WAITING
        self._pending_cc = message.command if isinstance(message, SystemCommand) else None

    def _server_sent(self, message: Message) -> None:
        if isinstance(message, Ok) and self._pending_cc is not None:
            self._apply_cc(self._pending_cc)
        self._pending_cc = None

    def _apply_cc(self, command: int) -> None:
        if command in BUFFER_SIZES:
            self.buffer_size = BUFFER_SIZES[command]
        elif command == CcCommand.SECURE_FILE_SEND:
            self.secure_send = True

    # -- receiving ---------------------------------------------------------------------------

    def receive_data(self, data: bytes) -> None:
        """Feed received bytes; ``b""`` means the peer closed the connection."""
        if data:
            if self.on_bytes is not None:
                self.on_bytes("recv", data)
            self._framer.feed(data)
        else:
            self._eof = True

    def next_event(self) -> Message | None:
        """Return the next message, or ``None`` when more bytes are needed.

        Client role: returns only answers; unsolicited ``M_CC`` go to :meth:`next_notice`.
        Raises :class:`UndecodableTelegram` for a whole telegram that does not decode, another
        :class:`RemoteProtocolError` when framing is lost or a telegram comes unasked, and
        :class:`PeerClosed` when the peer closed while a telegram was due.
        """
        while True:
            frame = self._framer.next_frame()
            if frame is None:
                if self._eof:
                    where = "mid-telegram" if self._framer.buffered else "mid-conversation"
                    raise PeerClosed(f"peer closed the connection {where}")
                return None
            self.last_frame = frame
            if self.role is Role.SERVER:
                try:  # inline, not _decode(): once per telegram
                    message = decode(frame)
                except RemoteProtocolError as exc:
                    raise UndecodableTelegram(frame, exc) from exc
                self._pending_cc = message.command if isinstance(message, SystemCommand) else None
                self._trace(message)
                return message
            if frame.mnemonic == "M_CC":
                notice = _decode(frame)
                assert isinstance(notice, CommandDone)
                self._notices.append(notice)
                self._trace(notice)
                continue
            if self.state is not State.WAITING:
                raise RemoteProtocolError(f"unsolicited {frame.mnemonic} telegram")
            self.state = State.IDLE
            pending, self._pending_cc = self._pending_cc, None
            try:
                message = decode(frame)
            except RemoteProtocolError as exc:
                raise UndecodableTelegram(frame, exc) from exc
            if pending is not None and isinstance(message, Ok):
                self._apply_cc(pending)
            self._trace(message)
            return message

    def next_notice(self) -> CommandDone | None:
        """Pop the oldest unsolicited ``M_CC`` received so far (client role)."""
        return self._notices.popleft() if self._notices else None

    def _trace(self, message: Message) -> None:
        if self.on_message is not None:
            self.on_message("recv", message)

    @property
    def closed(self) -> bool:
        """True once the peer closed the connection."""
        return self._eof
