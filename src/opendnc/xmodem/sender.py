"""Sans-IO XModem sender: the whole file in, blocks out, one ACK per block.

The receiver chooses the check: ``C`` asks for CRC-16, ``NAK`` for the 8-bit sum. A sender in
``Mode.CHECKSUM`` waits for a NAK (it ignores ``C`` so that a CRC receiver falls back); ``CRC``
and ``ONE_K`` follow whichever request comes first. 1K blocks need CRC, so a 1K sender started
by NAK sends 128-byte blocks, sends the tail of the file in 128-byte blocks where that is
shorter on the wire, and falls back to 128-byte blocks after repeated NAKs of a 1K block.

Stop-and-wait is strict: the next block goes out only after the ACK of the previous one
(lrzsz ``rx`` discards unread input after each ACK, so pipelining would lose blocks).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

from opendnc.errors import PeerClosed, TransferError, TransportTimeout
from opendnc.xmodem.events import (
    BlockDone,
    Completed,
    EngineBase,
    EotAnswer,
    FallbackToSmall,
    Retry,
    Started,
)
from opendnc.xmodem.framing import (
    ACK,
    CAN,
    CRC_REQUEST,
    EOT,
    LARGE,
    NAK,
    SMALL,
    Mode,
    encode_block,
)

# A remainder longer than this goes as one 1K block: seven 128-byte blocks plus their
# ACKs are shorter on the wire than one 1029-byte block, eight are not.
_TAIL_SMALL_LIMIT = 7 * SMALL
_EOT = bytes((EOT,))


@dataclass(frozen=True, slots=True)
class SenderConfig:
    """Limits and timeouts of the sender (seconds)."""

    start_timeout: float = 60.0  # the operator may need a while to start the receive
    # Wait for an ACK/NAK: longer than a receiver's 10 s block timeout, so that after a lost
    # ACK the receiver's NAK alone asks for the block again. With equal timers the sender's
    # resend and the receiver's NAK cross, the block goes twice, and the ACK of the duplicate
    # is taken for the next block's: a block skipped (seen on the virtual cable at 1e-4 in
    # ~10 % of 20 kB transfers, some of them truncated files that both ends called complete).
    ack_timeout: float = 15.0
    max_retries: int = 10  # repeats of one block before giving up (standard XModem)
    eot_timeout: float = 2.0  # lrzsz rx answers EOT only after about 1 s
    eot_retries: int = 3  # further EOTs before finishing without an answer
    # failed sends of one 1K block before switching to 128 bytes; only while every failure
    # was a NAK (see XmodemSender._on_nak)
    fallback_after: int = 3
    # Pause between an ACK and the next block. lrzsz rx flushes its input right after writing
    # each ACK; on a pty (no line delay) a block sent at once can land before that flush and
    # be lost (rx then waits 5 s and NAKs). About 1 ms avoids it; real lines need 0.
    turnaround: float = 0.0
    # Longest wait, after the ACK of block 1 when block 1 went out more than once, for the
    # answers to its copies. In checksum mode NAK means both "start" and "send again": the rest
    # of a Haas's start-request burst, read after block 1 went out, sends copies of block 1, and
    # the receiver ACKs each copy as a duplicate. Taking those ACKs for the next blocks' runs
    # the sender ahead until the receiver sees a block out of order and cancels
    # (docs/xmodem.md#repeated-blocks). The wait ends as soon as every copy is answered, and
    # never lasts more than a quarter of ``ack_timeout``: it must end well before the
    # receiver's own block timeout, or its NAK for block 2 would cross block 2.
    settle: float = 1.0


class SenderState(enum.Enum):
    """Where the sender is in the session."""

    WAIT_START = "wait_start"
    WAIT_ACK = "wait_ack"
    PAUSE = "pause"  # turnaround before the next block
    SETTLE = "settle"  # answers to block 1's copies still to come (SenderConfig.settle)
    WAIT_EOT_ACK = "wait_eot_ack"
    DONE = "done"


class XmodemSender(EngineBase):
    """Sends ``data`` as one XModem session.

    Feed it the receiver's bytes; it never touches I/O or a clock (see
    :mod:`opendnc.xmodem.events` for the driving contract).
    """

    def __init__(
        self,
        data: bytes,
        mode: Mode = Mode.ONE_K,
        config: SenderConfig | None = None,
        *,
        block_events: bool = True,
    ) -> None:
        """``block_events=False`` skips the per-block :class:`BlockDone` events (a driver with
        no progress or event handler sets it: nobody would read them)."""
        super().__init__()
        self._block_events = block_events
        self.mode = mode
        self.config = config or SenderConfig()
        self.state = SenderState.WAIT_START
        self.crc = mode.uses_crc
        self._data = memoryview(bytes(data))
        self._total = len(self._data)
        self._offset = 0  # payload bytes acknowledged so far
        self._seq = 1
        self._blocks = 0
        self._large_allowed = mode is Mode.ONE_K
        self._block = b""
        self._block_len = 0  # payload bytes carried by the current block
        # the block after the current one, built by prepare() while the ACK is on its way:
        # ((seq, offset, large allowed), frame, payload bytes)
        self._next: tuple[tuple[int, int, bool], bytes, int] | None = None
        self._failures = 0  # NAKs/timeouts of the current block (or of the EOT)
        self._copies = 0  # times the current block went out
        self._owed = 0  # answers still due for the copies of block 1 (SETTLE)
        self._unanswered = False  # the current block met a timeout: it may have arrived
        self._cans = 0  # consecutive CAN bytes seen
        self._eot_naks = 0
        self._waited = 0.0
        self._arm(min(self.config.start_timeout, self.config.ack_timeout))

    @property
    def total(self) -> int:
        """Payload bytes to send."""
        return self._total

    @property
    def sent(self) -> int:
        """Payload bytes acknowledged by the receiver."""
        return self._offset

    # -- inputs -------------------------------------------------------------------------

    def receive_data(self, data: bytes) -> None:
        """Handle bytes from the receiver (ACK, NAK, 'C', CAN; anything else is line noise)."""
        if self.finished:
            return
        if self.state is SenderState.WAIT_START:
            self._on_start_bytes(data)
            return
        if data == b"\x06" and self.state is SenderState.WAIT_ACK:  # the hot path: one ACK
            self._cans = 0
            self._on_ack()
            return
        for byte in data:
            if self.finished:
                return
            if byte == CAN:
                self._cans += 1
                if self._cans >= 2:
                    self._on_cancel()
                continue
            self._cans = 0
            if byte == ACK:
                self._on_ack()
            elif byte == NAK:
                self._on_nak("NAK")
            elif byte == CRC_REQUEST and self.state is SenderState.WAIT_ACK and self._seq == 1:
                # a start request repeated before block 1 got through: send block 1 again
                self._on_nak("repeated start request")
            elif self.state is SenderState.WAIT_ACK:
                self._unanswered = True  # a garbled answer: it may have been the ACK

    def timed_out(self) -> None:
        """The current timer ran out without an answer."""
        if self.finished or self.timer is None:
            return
        cfg = self.config
        if self.state is SenderState.WAIT_START:
            self._waited += self.timer.seconds
            if self._waited >= cfg.start_timeout:
                self._fail(
                    TransportTimeout(f"no XModem receiver started within {cfg.start_timeout:g} s"),
                    cancel_peer=False,
                )
            else:
                self._arm(min(cfg.start_timeout - self._waited, cfg.ack_timeout))
        elif self.state is SenderState.PAUSE:
            self._send_next_block()
        elif self.state is SenderState.SETTLE:
            self._next_after_turnaround()
        elif self.state is SenderState.WAIT_ACK:
            self._unanswered = True
            self._on_nak(f"no answer in {cfg.ack_timeout:g} s")
        elif self.state is SenderState.WAIT_EOT_ACK:
            self._failures += 1
            if self._failures > cfg.eot_retries:
                self._done(EotAnswer.NONE)
            else:
                self._events.append(Retry(self._seq, self._failures, "EOT not acknowledged"))
                self._send_eot()

    def peer_closed(self) -> None:
        """The link closed. After the EOT that still means success: every block was ACKed."""
        if self.finished:
            return
        if self.state is SenderState.WAIT_EOT_ACK:
            self._done(EotAnswer.CLOSED)
        else:
            self._fail(
                PeerClosed(f"link closed after {self._offset} of {self._total} bytes"),
                cancel_peer=False,
            )

    def cancel(self) -> None:
        """Abort locally: CAN CAN CAN goes to the receiver and the session fails."""
        if not self.finished:
            self._fail(TransferError("transfer cancelled by the user"), cancel_peer=True)

    # -- transitions --------------------------------------------------------------------

    def _on_start_bytes(self, data: bytes) -> None:
        for byte in data:
            if byte == CAN:
                self._cans += 1
                if self._cans >= 2:
                    self._fail(
                        TransferError("receiver cancelled before the first block"),
                        cancel_peer=False,
                    )
                    return
                continue
            self._cans = 0
            if byte == NAK:
                self.crc = False
            elif byte == CRC_REQUEST and self.mode is not Mode.CHECKSUM:
                self.crc = True
            else:
                continue
            if not self.crc:
                # 1K blocks exist only with CRC-16
                self._large_allowed = False
            self._events.append(Started(self.mode, self.crc))
            # any further NAK/'C' in this chunk were queued before we answered
            # (docs/xmodem.md#haas-captures,
            # Figure 24 shows a Haas sending three); they must not trigger a resend
            self._next_after_turnaround()
            return

    def _on_ack(self) -> None:
        if self.state is SenderState.WAIT_EOT_ACK:
            self._done(EotAnswer.ACK)
            return
        if self.state is SenderState.SETTLE:
            self._copy_answered()
            return
        if self.state is not SenderState.WAIT_ACK:
            return
        self._offset += self._block_len
        self._blocks += 1
        if self._block_events:
            self._events.append(BlockDone(self._seq, self._offset, self._total))
        self._seq = (self._seq + 1) & 0xFF
        self._failures = 0
        self._unanswered = False
        if self._copies > 1 and self._blocks == 1:
            # Block 1 went out again on a NAK or 'C' that may have been the rest of the
            # receiver's start requests: the copies' answers may still come, so let them pass
            # before block 2. (A NAK of a later block is unambiguous and costs no wait.)
            self.state = SenderState.SETTLE
            self._owed = self._copies - 1
            self._arm(min(self.config.settle, self.config.ack_timeout / 4))
            return
        self._next_after_turnaround()

    def _copy_answered(self) -> None:
        self._owed -= 1
        if self._owed <= 0:
            self._next_after_turnaround()

    def _on_nak(self, reason: str) -> None:
        if self.state is SenderState.WAIT_EOT_ACK:
            # the receiver did not take our EOT (line noise, or a receiver that NAKs the
            # first EOT on purpose): unlike silence, this must not end as a success
            self._eot_naks += 1
            if self._eot_naks > self.config.max_retries:
                self._fail(
                    TransferError(f"receiver refused EOT {self._eot_naks} times"),
                    cancel_peer=True,
                )
            else:
                self._events.append(Retry(self._seq, self._eot_naks, "EOT NAKed"))
                self._send_eot()
            return
        if self.state is SenderState.SETTLE:
            self._copy_answered()  # a copy that arrived damaged: block 1 itself was ACKed
            return
        if self.state is not SenderState.WAIT_ACK:
            return
        self._failures += 1
        if self._failures > self.config.max_retries:
            self._fail(
                TransferError(
                    f"block {self._seq} failed {self._failures} times ({reason}); "
                    f"{self._offset} of {self._total} bytes delivered"
                ),
                cancel_peer=True,
            )
            return
        self._events.append(Retry(self._seq, self._failures, reason))
        # Falling back re-cuts the block into 128-byte blocks numbered from the same sequence
        # number. If the receiver already holds the 1K block (its ACK was lost: a timeout),
        # it takes the first small block for a duplicate and the next ones for new data, and
        # the file silently grows by up to 896 bytes. Only NAKs prove it does not hold it.
        if (
            self._block_len > SMALL
            and self._failures >= self.config.fallback_after
            and not self._unanswered
        ):
            self._large_allowed = False
            self._events.append(FallbackToSmall(self._seq))
            self._build_block()
        self._emit(self._block)
        self._copies += 1
        self._arm(self.config.ack_timeout)

    def _on_cancel(self) -> None:
        if self.state is SenderState.WAIT_EOT_ACK:
            # a Haas answers the EOT of a complete transfer with CAN CAN CAN
            self._done(EotAnswer.CAN)
        else:
            self._fail(
                TransferError(
                    f"receiver cancelled the transfer at block {self._seq} "
                    f"({self._offset} of {self._total} bytes delivered)"
                ),
                cancel_peer=False,
            )

    def _next_after_turnaround(self) -> None:
        if self.config.turnaround > 0 and self._offset < self._total:
            self.state = SenderState.PAUSE
            self._arm(self.config.turnaround, listen=False)
        else:
            self._send_next_block()

    def prepare(self) -> None:
        """Build the next block while waiting for the ACK of the current one.

        On a paced line the sender sleeps through every block; the Python work of building
        the next one after the ACK arrives runs with cold caches and delays the line.
        """
        if self.state is not SenderState.WAIT_ACK or self._next is not None:
            return
        offset = self._offset + self._block_len
        if offset >= self._total:
            return
        seq = (self._seq + 1) & 0xFF
        frame, length = self._encode(seq, offset)
        self._next = ((seq, offset, self._large_allowed), frame, length)

    def _encode(self, seq: int, offset: int) -> tuple[bytes, int]:
        """The frame of the block at ``offset`` and the payload bytes it carries."""
        large = self._large_allowed and self._total - offset > _TAIL_SMALL_LIMIT
        chunk = self._data[offset : offset + (LARGE if large else SMALL)]
        return encode_block(seq, chunk, crc=self.crc, large=large), len(chunk)

    def _build_block(self) -> None:
        ready, self._next = self._next, None
        if ready is not None and ready[0] == (self._seq, self._offset, self._large_allowed):
            _, self._block, self._block_len = ready
            return
        self._block, self._block_len = self._encode(self._seq, self._offset)

    def _send_next_block(self) -> None:
        if self._offset >= self._total:
            self._failures = 0
            self._send_eot()
            return
        self.state = SenderState.WAIT_ACK
        self._build_block()
        self._emit(self._block)
        self._copies = 1
        self._arm(self.config.ack_timeout)

    def _send_eot(self) -> None:
        self.state = SenderState.WAIT_EOT_ACK
        self._emit(_EOT)
        self._arm(self.config.eot_timeout)

    def _done(self, answer: EotAnswer) -> None:
        self.state = SenderState.DONE
        self._finish(Completed(self._offset, self._blocks, answer))
