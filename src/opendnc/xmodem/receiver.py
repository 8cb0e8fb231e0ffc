"""Sans-IO XModem receiver: start requests out, blocks in, ACK/NAK per block.

The receiver asks for a start with ``C`` (CRC-16; falls back to ``NAK`` after a few tries,
as classic receivers do) or with ``NAK`` (8-bit sum, the Haas variant), repeated while idle.
SOH (128) and STX (1024) blocks are both accepted. A block received again because our ACK
was lost is ACKed and dropped; any other out-of-order block cancels the session, since data
would be lost. After an error the receiver waits for the line to go quiet, then NAKs.

``idle_timeout`` bounds the whole wait for the sender's next good block, retries included:
without it a sender that vanished without a hang-up the port can report (a cable pulled, a
virtual cable's far side gone) costs ``max_retries`` times ``block_timeout``. A hang-up the
port does report ends the session at once (:meth:`XmodemReceiver.peer_closed`).

With ``text_check`` every new block must continue an NC program text (:mod:`opendnc.nctext`):
a block that passed the checksum but breaks the text rules is NAKed like a bad block, so
damage that an 8-bit sum cannot see (two compensating bit errors) is sent again instead of
written. The same bad bytes arriving twice are in the sender's file: the session fails with
:class:`~opendnc.errors.ProgramTextError`.

A lone EOT or CAN pair at a block boundary is acted on only if no further bytes follow within
``settle`` seconds: line noise that turns a block's SOH into EOT (or a lost SOH that exposes
block number 4) must cause a NAK, never a truncated file.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

from opendnc.errors import (
    PeerClosed,
    ProgramTextError,
    RemoteProtocolError,
    TransferError,
    TransportTimeout,
)
from opendnc.nctext import TextScanner
from opendnc.xmodem.events import (
    Completed,
    DataReceived,
    Duplicate,
    EngineBase,
    EotAnswer,
    Retry,
    Started,
)
from opendnc.xmodem.framing import (
    ACK,
    CAN,
    CRC_REQUEST,
    EOT,
    NAK,
    SMALL,
    SOH,
    STX,
    SUB,
    Mode,
    decode_frame,
    frame_length,
)


@dataclass(frozen=True, slots=True)
class ReceiverConfig:
    """Limits and timeouts of the receiver (seconds)."""

    start_timeout: float = 60.0  # total wait for the sender to begin
    start_interval: float = 3.0  # repeat the start request this often while idle
    crc_tries: int = 3  # 'C' requests before falling back to NAK (0 = never fall back)
    block_timeout: float = 10.0  # wait for the next block before NAKing
    char_timeout: float = 1.0  # silence inside a block before NAKing it
    purge_quiet: float = 0.2  # after a bad block, silence needed before the NAK
    settle: float = 0.05  # silence that confirms a lone EOT or CAN pair
    max_retries: int = 10  # consecutive errors on one block before giving up
    # the longest wait for the next good block, retries included (None: retries bound it)
    idle_timeout: float | None = None
    strip_padding: bool = True  # drop trailing SUB (0x1A) from the final block
    fold_eob_checksum: bool = False  # Haas: accept sums computed with EOB folded to LF
    # ACK, or CAN (CAN CAN CAN: a Haas, docs/xmodem.md#haas-dialect)
    eot_answer: EotAnswer = EotAnswer.ACK
    text_start: bool = False
    """While waiting for the sender, end with :class:`PlainTextStart` when the first byte that
    is not line filler starts no block (a Haas in auto mode takes that as a drip-feed)."""
    cancel_when_idle: bool = True  # CAN the line when no sender starts; False for a port that
    # listens in windows (a DNC server between jobs), where a sender may answer the next one

    text_check: bool = False  # NAK blocks that are not NC program text (opendnc.nctext)


class PlainTextStart(RemoteProtocolError):
    """The sender began with plain text instead of an XModem block (``text_start``)."""

    def __init__(self, text: bytes) -> None:
        super().__init__("plain text instead of XModem")
        self.text = text


_ACK, _NAK, _C = bytes((ACK,)), bytes((NAK,)), bytes((CRC_REQUEST,))
_CAN3 = bytes((CAN, CAN, CAN))
_FILLER = b"\x00\r\n \x11\x13\x15"  # NUL, line ends, space, XON/XOFF, NAK (our echo)
_STARTERS = (b"\x01", b"\x02", b"\x04", b"\x18")  # SOH, STX, EOT, CAN


class ReceiverState(enum.Enum):
    """Where the receiver is in the session."""

    STARTING = "starting"
    RECEIVING = "receiving"
    SETTLING = "settling"  # saw EOT or CAN CAN, waiting for silence
    PURGING = "purging"  # saw garbage, waiting for silence before NAK
    DONE = "done"


class XmodemReceiver(EngineBase):
    """Receives one XModem session; file bytes come out as :class:`DataReceived` events."""

    def __init__(self, mode: Mode = Mode.CRC, config: ReceiverConfig | None = None) -> None:
        super().__init__()
        self.mode = mode
        self.config = config or ReceiverConfig()
        self.state = ReceiverState.STARTING
        self.crc = mode.uses_crc
        self._buf = bytearray()
        self._expected = 1
        self._blocks = 0
        self._size = 0  # bytes released through DataReceived
        self._held: bytes | None = None  # newest block, kept back until we know it is not the last
        self._recut: int | None = None  # next 128-byte slice of the held 1K block to expect
        self._errors = 0
        self._requests = 0
        self._waited = 0.0
        self._idle = 0.0  # timer seconds expired since the last good block
        limit = self.config.idle_timeout
        self._block_wait = self.config.block_timeout
        if limit is not None:
            self._block_wait = min(self._block_wait, limit)
        self._purge_reason = ""
        self._text = TextScanner() if self.config.text_check else None
        self._refused: bytes | None = None  # the last block NAKed for its text
        self._request_start()

    @property
    def received(self) -> int:
        """Payload bytes accepted so far (padding of the last block included)."""
        return self._size + (len(self._held) if self._held is not None else 0)

    # -- inputs -------------------------------------------------------------------------

    def receive_data(self, data: bytes) -> None:
        """Handle bytes from the sender."""
        if self.finished or not data:
            return
        state = self.state
        if state is ReceiverState.PURGING:
            self._arm(self.config.purge_quiet)
            return
        if state is ReceiverState.SETTLING:
            tail = bytes(self._buf) + data
            if tail.strip(bytes((tail[0],))):
                # more than the control byte arrived: it was noise inside a block
                self._buf.clear()
                self._purge()
            else:
                self._buf += data
            return
        if state is ReceiverState.RECEIVING:
            # the hot paths: a whole block in one read, or the read that completes the block
            # begun by earlier ones (a paced line delivers a block in pieces), decoded without
            # the general parser; this runs right before our ACK goes out
            buf = self._buf
            start = buf[0] if buf else data[0]
            if start in (SOH, STX) and len(buf) + len(data) == frame_length(start, self.crc):
                frame = bytes(buf) + data if buf else data
                buf.clear()
                if self._take_frame(frame) and not self.finished:
                    self._arm(self._block_wait)
                return
        if state is ReceiverState.STARTING:
            starts = [i for i in (data.find(c) for c in _STARTERS) if i >= 0]
            if self.config.text_start and data[: min(starts, default=len(data))].strip(_FILLER):
                self._fail(PlainTextStart(data), cancel_peer=False)
                return
            if not starts:
                return  # echo or noise while idle
            data = data[min(starts) :]
            self.state = ReceiverState.RECEIVING
            self._events.append(Started(self.mode, self.crc))
        self._buf += data
        self._parse()

    def timed_out(self) -> None:
        """The current timer ran out without input that re-armed it."""
        if self.finished or self.timer is None:
            return
        cfg = self.config
        state = self.state
        if state is ReceiverState.STARTING:
            self._waited += self.timer.seconds
            if self._waited >= cfg.start_timeout:
                self._fail(
                    TransportTimeout(f"no XModem sender started within {cfg.start_timeout:g} s"),
                    cancel_peer=cfg.cancel_when_idle,
                )
            else:
                self._request_start()
        elif state is ReceiverState.SETTLING:
            self._on_settled()  # the EOT (or CAN) was confirmed: not a wait for the sender
        elif cfg.idle_timeout is not None and self._idle_expired(self.timer.seconds):
            return
        elif state is ReceiverState.PURGING:
            self._nak(self._purge_reason)
        else:
            waited = self.timer.seconds
            reason = "incomplete block" if self._buf else f"no block in {waited:g} s"
            self._buf.clear()
            self._nak(reason)
        self._cap_timer()

    def _idle_expired(self, seconds: float) -> bool:
        """Count a timer that ran out; True (and the session failed) once the budget is used."""
        limit = self.config.idle_timeout
        assert limit is not None
        self._idle += seconds
        if self._idle < limit - 1e-9:
            return False
        self._buf.clear()
        self._fail(
            TransportTimeout(
                f"no good block from the sender for {limit:g} s (block {self._expected}, "
                f"{self.received} bytes received); transfer abandoned"
            ),
            cancel_peer=True,
        )
        return True

    def _cap_timer(self) -> None:
        """Keep the next wait within what is left of ``idle_timeout``."""
        limit = self.config.idle_timeout
        timer = self.timer
        if limit is None or timer is None or self.state is ReceiverState.STARTING:
            return
        left = limit - self._idle
        if timer.seconds > left:
            self._arm(max(left, 0.001), listen=timer.listen)

    def peer_closed(self) -> None:
        """The link closed before the sender's EOT."""
        if not self.finished:
            self._fail(
                PeerClosed(f"link closed after {self.received} bytes, before the end of the file"),
                cancel_peer=False,
            )

    def cancel(self) -> None:
        """Abort locally: CAN CAN CAN goes to the sender and the session fails."""
        if not self.finished:
            self._fail(TransferError("transfer cancelled by the user"), cancel_peer=True)

    # -- block parsing (the hot path: one pass per complete block, no per-byte loop) -----

    def _parse(self) -> None:
        buf = self._buf
        while buf:
            start = buf[0]
            if start in (SOH, STX):
                length = frame_length(start, self.crc)
                if len(buf) < length:
                    self._arm(self.config.char_timeout)
                    return
                # decode a copy: a view into buf would pin it while an error propagates
                frame = bytes(buf) if len(buf) == length else bytes(buf[:length])
                del buf[:length]
                if not self._take_frame(frame):
                    buf.clear()
                    return
                if self.finished:
                    return
                if buf and self.state is ReceiverState.RECEIVING:
                    # a well-behaved sender waits for our ACK, so anything already queued
                    # after a block is stale or noise
                    buf.clear()
                    return
            elif start in (EOT, CAN):
                self.state = ReceiverState.SETTLING
                self._arm(self.config.settle)
                if buf.strip(bytes((start,))):
                    buf.clear()
                    self._purge()
                return
            else:
                buf.clear()
                self._purge(f"unexpected byte 0x{start:02X} where a block should start")
                return
        self._arm(self._block_wait)

    def _take_frame(self, frame: bytes) -> bool:
        """Decode and act on one complete frame; False if it was bad (purging started)."""
        try:
            seq, data = decode_frame(frame, crc=self.crc, fold_eob=self.config.fold_eob_checksum)
        except RemoteProtocolError as exc:
            self._purge(str(exc))
            return False
        self._on_block(seq, data)
        return True

    def _on_block(self, seq: int, data: bytes) -> None:
        expected = self._expected
        if self._recut is not None and self._on_recut_slice(seq, data):
            return
        if seq == expected:
            if self._text is not None and not self._text_ok(seq, data):
                return
            if self._held is not None:
                self._size += len(self._held)
                self._events.append(DataReceived(self._held))
            self._held = data
            self._recut = None
            self._idle = 0.0
            self._blocks += 1
            self._expected = (expected + 1) & 0xFF
            self._errors = 0
            self._emit(_ACK)
        elif self._blocks and seq == ((expected - 1) & 0xFF):
            self._idle = 0.0  # the sender is alive: it repeats a block whose ACK it missed
            held = self._held
            recut = held is not None and len(held) > len(data) == SMALL and held[:SMALL] == data
            if recut and self._recut is None:
                # a 1K block we hold, re-cut into 128-byte blocks numbered from its own
                # sequence number (the sender fell back without seeing our ACK): the next
                # small blocks repeat the rest of it and must not be taken for new data
                self._recut = 1
            self._events.append(Duplicate(seq))
            self._emit(_ACK)
        else:
            self._fail(
                RemoteProtocolError(
                    f"block {seq} arrived while block {expected} was expected; "
                    "the sender is out of step, transfer cancelled"
                ),
                cancel_peer=True,
            )

    def _text_ok(self, seq: int, data: bytes) -> bool:
        """Keep a block that continues the program text; NAK one that breaks it."""
        assert self._text is not None
        trial = self._text.copy()
        trial.feed(data)
        problem = trial.problem
        if problem is None:
            self._text = trial
            self._refused = None
            return True
        if problem.offset < self._text.offset or data == self._refused:
            # in a block we already took, or the same bytes twice: it is in the sender's file
            self._fail(
                ProgramTextError(
                    problem,
                    what="received program",
                    action=(
                        "transfer cancelled, the file was not written (--binary receives any bytes)"
                    ),
                ),
                cancel_peer=True,
            )
            return False
        self._refused = data
        self._nak(f"block {seq}: not NC text, {problem.describe()}")
        return False

    def _on_recut_slice(self, seq: int, data: bytes) -> bool:
        """A small block that repeats a slice of the held 1K block: ACK and drop it."""
        held, index = self._held, self._recut
        assert held is not None
        assert index is not None
        if seq != self._expected or len(data) != SMALL:
            return False
        if held[index * SMALL : (index + 1) * SMALL] != data:
            self._fail(
                RemoteProtocolError(
                    f"block {seq} should repeat part of block {(seq - index) & 0xFF} after the "
                    "sender fell back to 128-byte blocks, but differs; transfer cancelled"
                ),
                cancel_peer=True,
            )
            return True
        self._recut = index + 1 if (index + 1) * SMALL < len(held) else None
        self._expected = (seq + 1) & 0xFF
        self._errors = 0
        self._idle = 0.0
        self._events.append(Duplicate(seq))
        self._emit(_ACK)
        return True

    def _on_settled(self) -> None:
        control = self._buf[0] if self._buf else EOT
        count = len(self._buf)
        self._buf.clear()
        if control == CAN:
            if count >= 2:
                self._fail(
                    TransferError(f"sender cancelled the transfer after {self.received} bytes"),
                    cancel_peer=False,
                )
            else:
                self._nak("single CAN")
            return
        # EOT: the file is complete
        if self._blocks == 0:
            self._emit(_ACK)
            self._fail(
                TransferError("the sender ended the session (EOT) before sending any block"),
                cancel_peer=False,
            )
            return
        if self._held is not None:
            last = self._held.rstrip(bytes((SUB,))) if self.config.strip_padding else self._held
            self._held = None
            if last:
                self._size += len(last)
                self._events.append(DataReceived(last))
        answer = self.config.eot_answer
        self._emit(_CAN3 if answer is EotAnswer.CAN else _ACK)
        self.state = ReceiverState.DONE
        self._finish(Completed(self._size, self._blocks, answer))

    # -- helpers ------------------------------------------------------------------------

    def _request_start(self) -> None:
        cfg = self.config
        if self.crc and cfg.crc_tries and self._requests >= cfg.crc_tries:
            self.crc = False  # the sender did not answer 'C': try the original checksum mode
        self._requests += 1
        self._emit(_C if self.crc else _NAK)
        self._arm(min(cfg.start_interval, max(cfg.start_timeout - self._waited, 0.001)))

    def _purge(self, reason: str = "line noise") -> None:
        self.state = ReceiverState.PURGING
        self._purge_reason = reason
        self._arm(self.config.purge_quiet)

    def _nak(self, reason: str) -> None:
        self._errors += 1
        if self._errors > self.config.max_retries:
            self._fail(
                TransferError(
                    f"block {self._expected} failed {self._errors} times ({reason}); "
                    f"{self.received} bytes received, transfer abandoned"
                ),
                cancel_peer=True,
            )
            return
        self._events.append(Retry(self._expected, self._errors, reason))
        self.state = ReceiverState.RECEIVING
        self._emit(_NAK if self._blocks or not self.crc else _C)
        self._arm(self.config.block_timeout)
