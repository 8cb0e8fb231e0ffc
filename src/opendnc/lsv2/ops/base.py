"""Building blocks of LSV2 operations: the generator protocol, session state, reply checks.

An *operation* is a generator that yields steps and is sent the replies; it performs no I/O,
so the blocking and asyncio drivers (:mod:`opendnc.lsv2.drive`) run the very same code::

    def change_dir(state, path):          # Op[None]
        yield from ensure_login(state, Login.FILE)
        yield from command(ChangeDir(path), f"change directory to {path}")

A step is a :class:`~opendnc.lsv2.messages.Message` to send (the reply is sent back in;
``None`` if the protocol defines no reply, e.g. ``T_FD`` without secure send), a
:class:`Slow` message with its own timeout, :class:`Expect` to wait for an unsolicited
``M_CC`` without sending anything, or the two halves of one exchange, :class:`Send` and
:class:`Receive`, between which the operation does its own work while the answer travels.
"""

from __future__ import annotations

from collections.abc import Generator
from dataclasses import dataclass, field
from typing import NoReturn, TypeVar

from opendnc.errors import ControlRefused, RemoteProtocolError, SafetyLockError
from opendnc.lsv2.constants import DEFAULT_BUFFER_SIZE, AttributeScheme, Family, Login
from opendnc.lsv2.messages import BlockDefect, Message, Ok, Refused
from opendnc.lsv2.messages import Login as LoginMsg
from opendnc.lsv2.payloads import SystemParameters, Versions

__all__ = [
    "Expect",
    "Op",
    "Receive",
    "Send",
    "SessionState",
    "Slow",
    "Step",
    "ask",
    "command",
    "ensure_login",
    "refuse",
    "require_unsafe",
    "wire_path",
]

T = TypeVar("T")
M = TypeVar("M", bound=Message)


@dataclass(frozen=True, slots=True)
class Slow:
    """Send ``message`` and allow ``timeout`` seconds for the answer (e.g. ``C_MC``)."""

    message: Message
    timeout: float


@dataclass(frozen=True, slots=True)
class Expect:
    """Send nothing; wait up to ``timeout`` seconds for an unsolicited ``M_CC``."""

    timeout: float


@dataclass(frozen=True, slots=True)
class Send:
    """Send ``message`` and come back at once (with ``None``); :class:`Receive` reads its answer.

    Transfers are stop-and-wait: a download block's ``T_OK`` should leave before the block is
    stored, so that storing it overlaps with the control preparing the next one. The
    operation stores between ``Send`` and ``Receive``, in its own code, and must take the
    answer (``Receive``) before it raises, so that the link stays in step.
    """

    message: Message


@dataclass(frozen=True, slots=True)
class Receive:
    """Wait for the answer to the preceding :class:`Send` (``None`` if none is due)."""


Step = Message | Slow | Expect | Send | Receive
Op = Generator[Step, Message | None, T]


TELEGRAM_FLOOR = 64
"""Smallest telegram an adaptive upload shrinks to (docs/lsv2-serial.md, "Telegram size")."""


@dataclass
class TelegramSizer:
    """Upload telegram size that follows the line (docs/lsv2-serial.md, "Telegram size").

    Fed with the tries every file block needed: after ``shrink_after`` retried blocks in a row
    the size halves (down to ``floor``), after ``grow_after`` clean blocks in a row it doubles
    (up to the ceiling: the negotiated buffer and the size asked for). Every change is kept in
    :attr:`changes` as ``(old, new)``.
    """

    ceiling: int = 4096
    floor: int = TELEGRAM_FLOOR
    shrink_after: int = 2
    grow_after: int = 16
    size: int = 0
    """Current telegram size (0: not started, the ceiling)."""
    changes: list[tuple[int, int]] = field(default_factory=list)
    _bad: int = 0
    _clean: int = 0
    _cap: int = 0  # the ceiling in force: the negotiated buffer, at most ``ceiling``

    def limit(self, ceiling: int) -> int:
        """Telegram size for the next block, within ``ceiling`` (the negotiated buffer)."""
        ceiling = min(ceiling, self.ceiling)
        self._cap = ceiling
        if self.size == 0 or self.size > ceiling:
            self.size = ceiling
        return max(min(self.size, ceiling), min(self.floor, ceiling))

    def block_sent(self, tries: int) -> None:
        """A file block of ours went through after ``tries`` transmissions."""
        if tries > 1:
            self._clean = 0
            self._bad += 1
            if self._bad >= self.shrink_after and self.size > self.floor:
                self._bad = 0
                self._change(max(self.floor, self.size // 2))
            return
        self._bad = 0
        self._clean += 1
        cap = self._cap or self.ceiling
        if self._clean >= self.grow_after and 0 < self.size < cap:
            self._clean = 0
            self._change(min(cap, self.size * 2))

    def _change(self, new: int) -> None:
        self.changes.append((self.size, new))
        self.size = new


@dataclass
class SessionState:
    """What a client knows about its session; ops read and update it, drivers keep it."""

    safe_mode: bool = True
    logins: set[str] = field(default_factory=set)
    passwords: dict[str, str] = field(default_factory=dict)
    """Passwords to use when an operation logs in automatically."""
    versions: Versions | None = None
    family: Family = Family.UNKNOWN
    params: SystemParameters | None = None
    buffer_size: int = DEFAULT_BUFFER_SIZE
    secure_send: bool = False
    connected: bool = False
    sizer: TelegramSizer | None = None
    """Set over serial LSV2: upload blocks follow the line (docs/lsv2-serial.md)."""

    @property
    def scheme(self) -> AttributeScheme:
        """Attribute-bit scheme of this control."""
        return self.family.attribute_scheme

    @property
    def data_limit(self) -> int:
        """Largest data block per ``S_FL`` (buffer minus header and a small margin)."""
        return self.buffer_size - 10

    @property
    def upload_limit(self) -> int:
        """Largest data block for the next upload ``S_FL`` (adaptive over serial)."""
        if self.sizer is None:
            return self.data_limit
        return self.sizer.limit(self.buffer_size) - 10

    def require_params(self) -> SystemParameters:
        """The system parameters (read during connect)."""
        if self.params is None:
            raise RemoteProtocolError("system parameters unknown: not connected")
        return self.params


def refuse(reply: Message | None, context: str) -> NoReturn:
    """Raise the typed error for an unwanted ``reply``."""
    if isinstance(reply, Refused | BlockDefect):
        code = reply.code if reply.code is not None else 0
        raise ControlRefused(code, reply.text, context=context)
    got = "no answer" if reply is None else reply.mnemonic
    raise RemoteProtocolError(f"{context}: unexpected {got}")


def expect(reply: Message | None, kind: type[M], context: str) -> M:
    """Return ``reply`` if it is a ``kind``; otherwise raise (``T_ER`` -> ControlRefused)."""
    if isinstance(reply, kind):
        return reply
    refuse(reply, context)


def ask(message: Message, kind: type[M], context: str) -> Op[M]:
    """Send ``message`` and return its answer of type ``kind``."""
    reply = yield message
    return expect(reply, kind, context)


def command(message: Message | Slow, context: str) -> Op[None]:
    """Send a command and require ``T_OK``."""
    reply = yield message
    expect(reply, Ok, context)


def try_command(message: Message, context: str) -> Op[bool]:
    """Send a command; ``True`` on ``T_OK``, ``False`` on ``T_ER``."""
    reply = yield message
    if isinstance(reply, Ok):
        return True
    if isinstance(reply, Refused):
        return False
    refuse(reply, context)


def ensure_login(state: SessionState, login: Login | str, password: str | None = None) -> Op[None]:
    """Log in as ``login`` unless this session already holds it."""
    name = str(login)
    if name in state.logins:
        return
    secret = password if password is not None else state.passwords.get(name)
    yield from command(LoginMsg(name, secret), f"login {name}")
    state.logins.add(name)
    if password is not None:
        state.passwords[name] = password


def require_unsafe(state: SessionState, action: str) -> None:
    """Refuse machine-changing ``action`` while safe mode is on."""
    if state.safe_mode:
        raise SafetyLockError(action)


def wire_path(path: str) -> str:
    """Controls separate with ``\\``; accept ``/`` from callers and collapse doubles."""
    p = path.replace("/", "\\")
    while "\\\\" in p:
        p = p.replace("\\\\", "\\")
    return p


def split_path(path: str) -> tuple[str, str]:
    """Split a wire path into (folder with trailing separator, name)."""
    p = wire_path(path).rstrip("\\")
    i = p.rfind("\\")
    if i < 0:
        j = p.find(":")
        return (p[: j + 1], p[j + 1 :]) if j >= 0 else ("", p)
    return p[: i + 1], p[i + 1 :]
