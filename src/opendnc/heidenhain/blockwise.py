"""Heidenhain's blockwise serial file protocol ("FE" modes), sans-IO (docs/lsv2-serial.md).

Not LSV2: a file is a header block naming it, then one block per program line, each with a
block check character and acknowledged on its own::

    header   SOH kind name 'E' ETB BCC     kind 'H': "here comes <name>" (the sender pushes)
                                           kind 'K': "send me <name>" (the receiver asks)
    line     STX text ETB BCC              one program line, without its line end
    answers  ACK (block good) / NAK (bad block check: send it again)
    flow     DC3 (stop sending) / DC1 (go on), from the receiver at any time
    end      ETX from the sender after the last line, EOT to close

BCC = XOR of every byte after SOH / STX up to and including ETB (what the seed's examples
allow; the reading of ISO 1745 block checks).

The iTNC 530 manual's table of the exchange lost its two columns in the public text, so who
sends which end character is our reading, chosen so the table stays consistent, and kept as
settings (:class:`BlockwiseSettings`):

* after its K header the receiver sends DC1 ("ready"); the sender answers the header with ACK;
* each line is answered with ACK or NAK by the receiver; a NAK'd line is sent again, at most
  ``retries`` times;
* after the last line's ACK the sender sends ETX and the receiver closes with EOT
  (``eot_by="receiver"``; ``"sender"`` makes the sender send ETX EOT and finish at once).

Every Heidenhain conversational line starts with its own line number, so two equal lines in
a row cannot be part of a program: a line equal to the previous one is taken for a repeat
whose ACK was lost (``drop_repeats``, default on).

Both engines do no I/O and read no clock: feed bytes and the time, write
:meth:`data_to_send`, call :meth:`tick` at :attr:`deadline`.
"""

from __future__ import annotations

import enum
from collections import deque
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from functools import reduce
from operator import xor
from typing import Literal

from opendnc.errors import InputError, TransferError, TransportTimeout

__all__ = [
    "BlockReceiver",
    "BlockSender",
    "BlockwiseSettings",
    "FileReceived",
    "FileRequested",
    "FileSent",
    "TransferFailed",
    "block_check",
    "encode_block",
    "encode_header",
    "join_lines",
    "split_lines",
]

SOH, STX, ETX, EOT, ACK, NAK, DC1, DC3, ETB = 0x01, 0x02, 0x03, 0x04, 0x06, 0x15, 0x11, 0x13, 0x17
_CONTROL = frozenset(range(0x20)) | {0x7F}


def block_check(content: bytes) -> int:
    """BCC of a block: XOR of the bytes after SOH/STX, ETB included."""
    return reduce(xor, content, 0)


def encode_header(kind: bytes, name: str) -> bytes:
    """``SOH kind name E ETB BCC``."""
    raw = name.encode("latin-1")
    if not raw or any(b in _CONTROL for b in raw):
        raise InputError(f"bad file name for the blockwise protocol: {name!r}")
    content = kind + raw + b"E" + bytes([ETB])
    return bytes([SOH]) + content + bytes([block_check(content)])


def encode_block(line: bytes) -> bytes:
    """``STX line ETB BCC``."""
    content = line + bytes([ETB])
    return bytes([STX]) + content + bytes([block_check(content)])


def split_lines(data: bytes) -> list[bytes]:
    """Program lines of ``data`` (CR LF or LF ends), refusing control characters in a line."""
    text = data[:-1] if data.endswith(b"\n") else data
    lines = [ln[:-1] if ln.endswith(b"\r") else ln for ln in text.split(b"\n")] if text else []
    for number, line in enumerate(lines, 1):
        bad = next((b for b in line if b in _CONTROL), None)
        if bad is not None:
            raise InputError(f"line {number} holds control character 0x{bad:02X}")
    return lines


def join_lines(lines: Iterable[bytes], line_end: bytes = b"\r\n") -> bytes:
    """A file of ``lines``, each ended with ``line_end``."""
    return b"".join(line + line_end for line in lines)


@dataclass(frozen=True, slots=True)
class BlockwiseSettings:
    """Choices of the blockwise protocol (see the module docstring)."""

    ack_timeout: float = 5.0
    """Seconds to wait for ACK/NAK of a header or line (and for EOT after ETX)."""
    idle_timeout: float = 30.0
    """Seconds a receiver waits for the next block before giving up."""
    retries: int = 3
    """Repeats of a NAK'd or unanswered block before the transfer fails."""
    eot_by: Literal["receiver", "sender"] = "receiver"
    drop_repeats: bool = True


DEFAULT_SETTINGS = BlockwiseSettings()


@dataclass(frozen=True, slots=True)
class FileSent:
    """The sender finished: every line was acknowledged."""

    name: str
    lines: int
    resent: int


@dataclass(frozen=True, slots=True)
class FileReceived:
    """The receiver got a whole file."""

    name: str
    lines: list[bytes] = field(repr=False)
    naks: int = 0


@dataclass(frozen=True, slots=True)
class FileRequested:
    """A receiver asked for ``name`` (K header); answer with :meth:`BlockSender.serve`."""

    name: str


@dataclass(frozen=True, slots=True)
class TransferFailed:
    """The transfer was given up."""

    error: TransferError | TransportTimeout


Event = FileSent | FileReceived | FileRequested | TransferFailed


class _Parser:
    """Cuts the line into header blocks, line blocks and single control characters."""

    def __init__(self, skip_lost_blocks: bool = False) -> None:
        self._buf = bytearray()
        self.garbage = 0
        self.skip_lost_blocks = skip_lost_blocks
        # After text outside a block (a block whose SOH/STX was spoilt), skip to its ETB and
        # BCC: that BCC may have any value, ETX and EOT included, and must not end the file.
        self._skipping = False
        # Offsets into _buf of characters the port marked as failing their parity check.
        self._bad: list[int] = []

    def feed(self, data: bytes, errors: Sequence[int] = ()) -> None:
        base = len(self._buf)
        self._buf += data
        if errors:
            self._bad.extend(base + i for i in errors)

    def _drop(self, count: int) -> bool:
        """Delete the first ``count`` bytes; True if a marked character was among them."""
        del self._buf[:count]
        if not self._bad:
            return False
        hit = any(i < count for i in self._bad)
        self._bad = [i - count for i in self._bad if i >= count]
        return hit

    def next(self) -> tuple[str, bytes, bool] | None:
        """``("header"|"block", content, bcc_ok)``, ``("char", b"\\x06", True)`` or None."""
        buf = self._buf
        while buf:
            first = buf[0]
            if first in (SOH, STX):
                end = buf.find(bytes([ETB]), 1)
                if end < 0:
                    # An unterminated block: wait, unless a new block start shows it was cut.
                    restart = max(buf.find(bytes([SOH]), 1), buf.find(bytes([STX]), 1))
                    if restart > 0:
                        self.garbage += restart
                        self._drop(restart)
                        continue
                    return None
                if end + 1 >= len(buf):
                    return None  # BCC still to come
                content = bytes(buf[1 : end + 1])
                check = buf[end + 1]
                marked = self._drop(end + 2)  # a marked character spoils the block
                kind = "header" if first == SOH else "block"
                return kind, content, block_check(content) == check and not marked
            if self._skipping:
                end = buf.find(bytes([ETB]))
                starts = [i for i in (buf.find(bytes([SOH])), buf.find(bytes([STX]))) if i >= 0]
                start = min(starts) if starts else -1
                if start >= 0 and (end < 0 or start < end):
                    self.garbage += start
                    self._drop(start)
                    self._skipping = False
                    continue
                if end < 0 or end + 1 >= len(buf):
                    return None  # wait for the ETB and the BCC after it
                self.garbage += end + 2
                self._drop(end + 2)
                self._skipping = False
                continue
            if self._drop(1):
                # A character nobody can read. If it was a block's SOH/STX, the text after it
                # starts the skipping below; if it was an ETX, the sender repeats it.
                self.garbage += 1
                continue
            if first in (ACK, NAK, DC1, DC3, ETX, EOT):
                return "char", bytes([first]), True
            self.garbage += 1
            if self.skip_lost_blocks and (first >= 0x20 or first == 0):
                # text (or a NUL from a parity error) outside a block: a block lost its start
                self._skipping = True
        return None


class _Engine:
    def __init__(self, settings: BlockwiseSettings, *, skip_lost_blocks: bool = False) -> None:
        self.settings = settings
        self._tx = bytearray()
        self._events: deque[Event] = deque()
        self._parser = _Parser(skip_lost_blocks)
        self.deadline: float | None = None
        self.done = False

    def data_to_send(self) -> bytes:
        """Bytes to write now."""
        data = bytes(self._tx)
        self._tx.clear()
        return data

    def next_event(self) -> Event | None:
        """Oldest event not yet returned."""
        return self._events.popleft() if self._events else None

    def receive_data(self, data: bytes, now: float, errors: Sequence[int] = ()) -> None:
        """Feed bytes read from the line; ``errors`` are indices into ``data`` of characters
        that failed their parity check (:class:`~opendnc.transport.marks.LineData`): the block
        holding one is answered NAK whatever its BCC says."""
        self._parser.feed(data, errors)
        while not self.done and (item := self._parser.next()) is not None:
            self._on(item, now)

    def tick(self, now: float) -> None:
        """Handle an expired :attr:`deadline`."""
        if self.deadline is not None and now >= self.deadline and not self.done:
            self.deadline = None
            self._timeout(now)

    def _fail(self, error: TransferError | TransportTimeout) -> None:
        self.done = True
        self.deadline = None
        self._events.append(TransferFailed(error))

    def _on(self, item: tuple[str, bytes, bool], now: float) -> None:
        raise NotImplementedError

    def _timeout(self, now: float) -> None:
        raise NotImplementedError


class _SendState(enum.Enum):
    WAIT_REQUEST = "waiting for a K header"
    HEADER = "sent header"
    LINE = "sent a line"
    END = "sent ETX"


class BlockSender(_Engine):
    """Sends one file: pushes it with an H header, or (``name=None``) waits for a K request."""

    def __init__(
        self,
        name: str | None,
        lines: list[bytes] | None = None,
        *,
        settings: BlockwiseSettings = DEFAULT_SETTINGS,
    ) -> None:
        super().__init__(settings)
        self.name = name or ""
        self.lines = list(lines or [])
        self.resent = 0
        self._index = -1  # -1: the header
        self._tries = 0
        self._paused = False
        self._state = _SendState.WAIT_REQUEST

    def start(self, now: float) -> None:
        """Push the H header (or start waiting for a request when no name was given)."""
        if self.name:
            self._state = _SendState.HEADER
            self._send_current(now)
        else:
            self.deadline = now + self.settings.idle_timeout

    def serve(self, lines: list[bytes] | None, now: float) -> None:
        """Answer a :class:`FileRequested`: the file's lines, or ``None`` (NAK: not here)."""
        if lines is None:
            self._tx.append(NAK)
            self.deadline = now + self.settings.idle_timeout
            return
        self.lines = list(lines)
        self._tx.append(ACK)
        self._index = 0
        self._tries = 0
        self._state = _SendState.LINE
        self._send_current(now)

    def _current(self) -> bytes:
        if self._index < 0:
            return encode_header(b"H", self.name)
        if self._index < len(self.lines):
            return encode_block(self.lines[self._index])
        return bytes([ETX])

    def _send_current(self, now: float) -> None:
        if self._index >= len(self.lines):
            self._state = _SendState.END
            if self.settings.eot_by == "sender":
                self._tx += bytes([ETX, EOT])
                self._finish()
                return
        if self._paused:
            self.deadline = now + self.settings.idle_timeout
            return
        self._tries += 1
        self._tx += self._current()
        self.deadline = now + self.settings.ack_timeout

    def _finish(self) -> None:
        self.done = True
        self.deadline = None
        self._events.append(FileSent(self.name, len(self.lines), self.resent))

    def _advance(self, now: float) -> None:
        self._index += 1
        self._tries = 0
        self._state = _SendState.LINE
        self._send_current(now)

    def _again(self, now: float, why: str) -> None:
        if self._tries > self.settings.retries:
            what = "header" if self._index < 0 else f"line {self._index + 1}"
            self._fail(TransferError(f"blockwise send of {self.name}: {what} {why}"))
            return
        self.resent += 1
        self._send_current(now)

    def _on(self, item: tuple[str, bytes, bool], now: float) -> None:
        kind, content, ok = item
        state = self._state
        if state is _SendState.WAIT_REQUEST:
            if kind == "header" and content[:1] == b"K" and content.endswith(b"E\x17"):
                if not ok:
                    self._tx.append(NAK)
                    return
                self.name = content[1:-2].decode("latin-1")
                self.deadline = None
                self._events.append(FileRequested(self.name))
            return
        if kind != "char":
            return  # our own echo or garbage: a sender takes only characters
        c = content[0]
        if c == DC3:
            self._paused = True
            return
        if c == DC1:
            if self._paused:
                self._paused = False
                if state is not _SendState.END:
                    self._send_current(now)
            return
        if state is _SendState.END:
            if c == EOT:
                self._finish()
            elif c == NAK:
                self._tx.append(ETX)
            return
        if c == ACK:
            self._advance(now)
        elif c == NAK:
            self._again(now, "refused with NAK on every try")

    def _timeout(self, now: float) -> None:
        if self._state is _SendState.WAIT_REQUEST:
            self._fail(TransportTimeout("no request for a file arrived"))
        elif self._state is _SendState.END:
            if self._tries > self.settings.retries:
                self._fail(TransferError(f"blockwise send of {self.name}: no EOT after ETX"))
            else:
                self._tries += 1
                self._tx.append(ETX)
                self.deadline = now + self.settings.ack_timeout
        elif self._paused:
            self._fail(TransportTimeout(f"blockwise send of {self.name}: held by DC3 too long"))
        else:
            self._again(now, "never acknowledged")


class BlockReceiver(_Engine):
    """Receives one file: waits for an H header, or asks for ``request`` with a K header."""

    def __init__(
        self, request: str | None = None, *, settings: BlockwiseSettings = DEFAULT_SETTINGS
    ) -> None:
        super().__init__(settings, skip_lost_blocks=True)
        self.request = request
        self.name = request or ""
        self.lines: list[bytes] = []
        self.naks = 0
        self._started = False
        self._tries = 0
        self._last: bytes | None = None

    def start(self, now: float) -> None:
        """Send the K header (with ``request``), or start waiting for a pushed file."""
        if self.request:
            self._ask(now)
        else:
            self.deadline = now + self.settings.idle_timeout

    def _ask(self, now: float) -> None:
        assert self.request is not None
        self._tries += 1
        self._tx += encode_header(b"K", self.request) + bytes([DC1])
        self.deadline = now + self.settings.ack_timeout

    def pause(self) -> None:
        """Ask the sender to hold (DC3); :meth:`resume` lets it go on (DC1)."""
        self._tx.append(DC3)

    def resume(self) -> None:
        """Let the sender go on (DC1)."""
        self._tx.append(DC1)

    def _on(self, item: tuple[str, bytes, bool], now: float) -> None:
        kind, content, ok = item
        if not self._started:
            if self.request and kind == "char" and content[0] == ACK:
                self._started = True
                self.deadline = now + self.settings.idle_timeout
            elif self.request and kind == "char" and content[0] == NAK:
                self._fail(TransferError(f"the control has no file {self.request}"))
            elif not self.request and kind == "header" and content[:1] == b"H":
                if (
                    not ok
                    or not content.endswith(b"E\x17")
                    or any(b in _CONTROL for b in content[:-2])
                ):
                    self.naks += 1
                    self._tx.append(NAK)
                    return
                self.name = content[1:-2].decode("latin-1")
                self._started = True
                self._tx.append(ACK)
                self.deadline = now + self.settings.idle_timeout
            return
        if kind == "header" and content[:1] == b"H" and ok and not self.lines:
            self._tx.append(ACK)  # our ACK of the header was lost: the sender repeats it
            return
        if kind == "block":
            # Program lines are printable: a control character (a NUL is what a UART hands over
            # for a character that failed its parity check) spoils the block like a bad BCC.
            if ok and any(b in _CONTROL for b in content[:-1]):
                ok = False
            if not ok:
                self.naks += 1
                self._tx.append(NAK)
            else:
                line = content[:-1]
                if not (self.settings.drop_repeats and line == self._last):
                    self.lines.append(line)
                self._last = line
                self._tx.append(ACK)
            self.deadline = now + self.settings.idle_timeout
            return
        if kind == "char" and content[0] == ETX:
            if self.settings.eot_by == "receiver":
                self._tx.append(EOT)
            self._complete()
        elif kind == "char" and content[0] == EOT:
            self._complete()

    def _complete(self) -> None:
        self.done = True
        self.deadline = None
        self._events.append(FileReceived(self.name, self.lines, self.naks))

    def _timeout(self, now: float) -> None:
        if self.request and not self._started and self._tries <= self.settings.retries:
            self._ask(now)
            return
        where = f"{len(self.lines)} lines of {self.name}" if self._started else "a file"
        self._fail(TransportTimeout(f"blockwise receive: no data after {where}"))
