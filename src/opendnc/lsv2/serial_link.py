"""Sans-IO link engine of LSV2 over RS-232, for either end of the line (docs/lsv2-serial.md).

Serial LSV2 carries the same telegrams as TCP, one per *transmission*, and every transmission
has three phases (docs/lsv2-serial.md, "Link handshake")::

    sender                      receiver
    ENQ                  ->                    request: "I want to send"
                         <-     DLE '0'        ready
    DLE STX body DLE ETX BCC ->                transfer (body DLE-stuffed)
                         <-     DLE '1' / NAK  received / bad block
    EOT                  ->                    end: the line is idle again

A request and its answer are two transmissions with the roles swapped: after the client's EOT
the control sends its own ENQ. :class:`SerialLink` implements both ends. It does no I/O and
reads no clock: the driver passes ``now`` (seconds, any monotonic origin) to every call, writes
:meth:`SerialLink.data_to_send`, and calls :meth:`SerialLink.tick` at
:attr:`SerialLink.deadline`.

Choices where the public sources are silent (each is a setting or documented here):

* **Retries** — a NAK or a missing acknowledgement ends the transmission with EOT and the whole
  transmission is repeated, at most ``retries`` times after the first try (default 3); then the
  telegram is dropped and :class:`LinkFailed` reports a :class:`SerialLinkError` carrying the
  host status code of docs/lsv2-serial.md ("Host status codes").
* **Collisions** — when both ends send ENQ, the client yields: it answers DLE '0', receives the
  control's telegram and then sends its own. The control ignores the client's ENQ.
* **Implicit acknowledgement** — an ENQ received while waiting for DLE '1' may mean the peer
  has ended the exchange and moved on (its DLE '1' was lost, it timed out waiting for our EOT
  and now sends its own telegram). It may as well be the peer's NAK with one bit changed
  (NAK 0x15 and ENQ 0x05 differ in one bit), so the ENQ alone proves nothing. The engine
  answers DLE '0' and counts our telegram as delivered only when the peer then sends a *new*
  telegram intact: LSV2 alternates requests and answers, so the peer speaks only after it has
  ours. If no telegram comes (the "ENQ" was a spoilt NAK and the peer waits for EOT), the
  receive phase times out and our telegram is sent again. The client does the same when the
  control's ENQ collides with a *repeat* of a telegram already framed once (an unsolicited
  ``M_CC`` racing a spoilt acknowledgement is the one case this reading gets wrong; the
  operation then times out).
* **Repeats** — a receiver whose DLE '1' was lost gets the same telegram again. With
  ``drop_repeats`` (default) a telegram identical to the previous one received, with nothing
  of ours framed in between, is acknowledged but not delivered twice. Answers can be alike
  (``T_OK`` after every file block): once ours went out, an equal telegram confirms ours only
  if the peer answered our DLE '1' for its previous one with EOT at once; if every frame of
  ours was refused with NAK it is the peer's repeat; otherwise ours fails with a typed error
  rather than a guess that could lose or double a file block. And a
  receiver that yielded and then refused the peer's block (or saw none) waits LSV2TIME1 for
  the peer to repeat it before repeating its own (docs/lsv2-serial.md, "Equal telegrams in a
  row").
* **Parity marks** — characters the port marked as failing their parity check
  (:meth:`SerialLink.receive_data` ``errors``) spoil their block (docs/lsv2-serial.md,
  "Parity errors").
* **Garbage** — bytes that are not part of the handshake or a frame are counted and ignored,
  except right after our DLE '0': then they are a block whose DLE STX was lost, read to its end
  and refused with NAK, so that payload bytes are not taken for ENQ or EOT. DLE DLE outside a
  block counts as one DLE.
* **Late NAK** — a NAK while waiting for DLE '0' refuses the block of the previous try, which
  swallowed our retry ENQ: the ENQ is sent again at once (once per try).
* **Link check** — :meth:`SerialLink.check_link` sends the lone ENQ that TNCremo sends before
  its first telegram; the peer's DLE '0' is answered by the next ENQ (or by EOT if nothing is
  queued), exactly as in the seed capture.
"""

from __future__ import annotations

import enum
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Literal

from opendnc.errors import InputError, TransportError, TransportTimeout
from opendnc.lsv2.framing import DLE, ENQ, EOT, ETX, NAK, STX, Frame, bcc, encode_serial_frame

__all__ = [
    "DEFAULT_TIMING",
    "HostStatus",
    "LinkEvent",
    "LinkFailed",
    "LinkRole",
    "LinkStats",
    "LinkTiming",
    "SerialLink",
    "SerialLinkError",
    "SerialLinkTimeout",
    "TelegramReceived",
    "TelegramSent",
    "describe_link_bytes",
]

READY = b"\x10\x30"  # DLE '0'
RECEIVED = b"\x10\x31"  # DLE '1'
_ENQ = bytes([ENQ])
_EOT = bytes([EOT])
_NAK = bytes([NAK])
_DLE_B = bytes([DLE])
_DLE_DLE = _DLE_B * 2

Direction = Literal["send", "recv"]
CharHook = Callable[[Direction, bytes], None]


class HostStatus(enum.IntEnum):
    """Host-side status codes of the LSV2 toolbox (docs/lsv2-serial.md, "Host status codes")."""

    OK = 0
    TIMEOUT = 1
    NO_ENQ = 2
    TIMEOUT2 = 3
    WRONG_CHAR = 4
    TOO_LONG = 5
    WRONG_BCC = 6
    NO_EOT = 7
    AP_ERROR = 8
    AP_COLLISION = 9
    NO_QUITT = 10
    TX_ERROR = 11
    TIMEOUT3 = 12
    COM_CLOSED = 13
    NO_OPEN = 14
    WRONG_PARAMS = 15
    NO_MESSAGE = 16
    NO_ACK = 17
    MSG_OK = 19
    BUSY = 90
    NO_CONNECT = 92
    UNKNOWN = 99


_STATUS_TEXT: dict[HostStatus, str] = {
    HostStatus.TIMEOUT: "receive timeout",
    HostStatus.NO_ENQ: "the peer did not answer ENQ with DLE 0",
    HostStatus.TIMEOUT2: "no valid character after DLE 0",
    HostStatus.WRONG_CHAR: "unexpected character",
    HostStatus.TOO_LONG: "telegram too long",
    HostStatus.WRONG_BCC: "block check character wrong",
    HostStatus.NO_EOT: "EOT missing",
    HostStatus.AP_COLLISION: "collision: both sides want to send",
    HostStatus.NO_QUITT: "telegram not acknowledged (no DLE 1)",
    HostStatus.TX_ERROR: "telegram refused with NAK on every try",
    HostStatus.COM_CLOSED: "port closed",
    HostStatus.NO_OPEN: "port could not be opened",
    HostStatus.WRONG_PARAMS: "bad port parameters",
    HostStatus.NO_ACK: "no acknowledge",
    HostStatus.NO_CONNECT: "no connection",
}


class SerialLinkError(TransportError):
    """The serial LSV2 link failed; ``status`` is the host status code (docs/lsv2-serial.md)."""

    def __init__(self, status: HostStatus, detail: str = "") -> None:
        self.status = status
        text = _STATUS_TEXT.get(status, status.name.lower().replace("_", " "))
        message = f"serial LSV2 link: {text} (host status {int(status)} {status.name})"
        super().__init__(f"{message}: {detail}" if detail else message)


class SerialLinkTimeout(SerialLinkError, TransportTimeout):
    """The serial link failed because the peer fell silent."""


@dataclass(frozen=True, slots=True)
class LinkTiming:
    """LSV2TIME0/1/2 in seconds (docs/lsv2-serial.md, "Timing"); each 0.001-3.6 s."""

    time0: float = 3.0
    """Receiving one whole block, DLE STX to BCC."""
    time1: float = 3.0
    """Waiting for the answer to ENQ or to the BCC."""
    time2: float = 1.0
    """After sending DLE 0, DLE 1 or NAK: waiting for the next valid character."""

    def __post_init__(self) -> None:
        for name in ("time0", "time1", "time2"):
            value = getattr(self, name)
            if not 0.001 <= value <= 3.6:
                raise InputError(f"LSV2 {name.upper()} must be 0.001-3.6 s, got {value:g}")


DEFAULT_TIMING = LinkTiming()


class LinkRole(enum.Enum):
    """Which end of the line the engine plays (decides who yields on a collision)."""

    CLIENT = "client"
    CONTROL = "control"


@dataclass(frozen=True, slots=True)
class TelegramReceived:
    """A telegram arrived intact (already acknowledged with DLE 1)."""

    frame: Frame


@dataclass(frozen=True, slots=True)
class TelegramSent:
    """The peer acknowledged our telegram; ``tries`` transmissions were needed."""

    frame: Frame
    tries: int


@dataclass(frozen=True, slots=True)
class LinkChecked:
    """The peer answered the link-check ENQ with DLE 0."""


@dataclass(frozen=True, slots=True)
class LinkFailed:
    """A queued telegram (or the link check) was given up; ``frame`` is ``None`` for a check."""

    frame: Frame | None
    error: SerialLinkError


LinkEvent = TelegramReceived | TelegramSent | LinkChecked | LinkFailed


@dataclass(slots=True)
class LinkStats:
    """Counters of what happened on the line (reported by traces and tests)."""

    sent: int = 0
    received: int = 0
    retries: int = 0
    naks_sent: int = 0
    naks_received: int = 0
    timeouts: int = 0
    collisions: int = 0
    repeats_dropped: int = 0
    implicit_acks: int = 0
    garbage: int = 0
    failures: int = 0
    line_errors: int = 0
    """Characters the port marked as failing their parity or framing check."""
    ambiguous: int = 0
    """Telegrams given up because the peer's answer could be a repeat (see the docs)."""


class _S(enum.Enum):
    IDLE = "idle"
    SEND_READY = "sent ENQ, waiting for DLE 0"
    SEND_ACK = "sent frame, waiting for DLE 1"
    RECV_START = "sent DLE 0, waiting for DLE STX"
    RECV_FRAME = "receiving a frame"
    RECV_END = "sent DLE 1 or NAK, waiting for EOT"
    AWAIT_REPEAT = "refused the peer's block, waiting for it again before repeating ours"


@dataclass(slots=True)
class _Outgoing:
    frame: Frame | None  # None: the link check
    wire: bytes
    tries: int = 0
    framed: bool = False  # the frame went out at least once: the peer may hold it
    enq_again: bool = False  # this try's ENQ was repeated after a late NAK
    prior_body: bytes | None = None  # the peer's last telegram when ours was first framed
    prior_confirmed: bool = False  # ... and the peer had our DLE 1 for it (its EOT came)
    unrefused: int = 0  # times framed and not answered with NAK: the peer may have taken it
    failures: list[HostStatus] = field(default_factory=list)


class SerialLink:
    """Both ends of serial LSV2 as one sans-IO state machine (see the module docstring)."""

    def __init__(
        self,
        role: LinkRole,
        *,
        timing: LinkTiming = DEFAULT_TIMING,
        retries: int = 3,
        max_body: int = 4096,
        drop_repeats: bool = True,
        on_bytes: CharHook | None = None,
        nak_retries: int | None = None,
    ) -> None:
        if retries < 0:
            raise InputError(f"retries must be 0 or more, got {retries}")
        self.role = role
        self.timing = timing
        self.retries = retries
        self.nak_retries = retries if nak_retries is None else max(retries, nak_retries)
        """Repeats allowed while the peer refuses with NAK: it is there and reading, so a
        noisy line gets more tries than a silent peer (default: ``retries``)."""
        self.max_body = max_body
        """Largest telegram body (name + payload) accepted; longer blocks are refused (NAK)."""
        self.drop_repeats = drop_repeats
        self.on_bytes = on_bytes
        """Called with ``("send"|"recv", bytes)`` for every chunk written or fed (traces)."""
        self.stats = LinkStats()
        self._state = _S.IDLE
        self._deadline: float | None = None
        self._out: deque[_Outgoing] = deque()
        self._events: deque[LinkEvent] = deque()
        self._tx = bytearray()
        self._dle = False  # a DLE ended the last chunk outside a frame
        self._frame = bytearray()  # raw (stuffed) bytes after DLE STX
        self._scan = 0
        self._spoilt = False  # the block being read began without its DLE STX
        self._last_body: bytes | None = None
        # The peer answered our DLE 1 for its last telegram with EOT: it had the DLE 1 and
        # will never send that telegram again (docs/lsv2-serial.md, "Equal telegrams in a row").
        self._last_confirmed = False
        self._acked_last = False  # this receive phase ended its block with DLE 1 (not NAK)
        self._acked_at = 0.0  # when that DLE 1 went out
        # We yielded to the peer's ENQ while our framed telegram waited for its DLE 1 (or for
        # DLE 0 of a repeat): a new telegram from the peer in this receive phase acknowledges it.
        self._ack_by_answer: HostStatus | None = None
        # This receive phase refused a block (NAK): the peer was sending a telegram.
        self._phase_failed = False
        self._await_status: HostStatus | None = None  # what AWAIT_REPEAT retries with

    # -- public API ----------------------------------------------------------------------------

    @property
    def state(self) -> str:
        """Readable name of the current link state."""
        return self._state.value

    @property
    def idle(self) -> bool:
        """True when no transmission is under way in either direction and none is queued."""
        return self._state is _S.IDLE and not self._out

    @property
    def busy_sending(self) -> bool:
        """True while telegrams of ours wait for, or are in, a transmission."""
        return bool(self._out)

    @property
    def deadline(self) -> float | None:
        """Time at which :meth:`tick` must be called, or ``None`` while the line is idle."""
        return self._deadline

    def send(self, frame: Frame, now: float) -> None:
        """Queue ``frame``; it goes out as soon as the line is free."""
        body = frame.body
        if len(body) > self.max_body:
            raise InputError(f"{frame.mnemonic} of {len(body)} bytes exceeds {self.max_body}")
        self._out.append(_Outgoing(frame, encode_serial_frame(body)))
        self._start_next(now)

    def check_link(self, now: float) -> None:
        """Queue the lone link-check ENQ (answered DLE 0 gives :class:`LinkChecked`)."""
        self._out.append(_Outgoing(None, b""))
        self._start_next(now)

    def receive_data(self, data: bytes, now: float, errors: Sequence[int] = ()) -> None:
        """Feed bytes read from the line.

        ``errors`` are indices into ``data`` of characters the port marked as failing their
        parity or framing check (:class:`~opendnc.transport.marks.LineData`): such a character
        spoils the block it belongs to (NAK), whatever its value, and outside a block it is
        noise. Without marks two bad characters can cancel in the XOR block check
        (docs/lsv2-serial.md, "Parity errors").
        """
        if not data:
            return
        if self.on_bytes is not None:
            self.on_bytes("recv", data)
        if not errors:
            self._feed(bytes(data), now)
            return
        start = 0
        for index in sorted(set(errors)):
            if index > start:
                self._feed(bytes(data[start:index]), now)
            self._line_error(now)
            start = index + 1
        if start < len(data):
            self._feed(bytes(data[start:]), now)

    def tick(self, now: float) -> None:
        """Handle an expired :attr:`deadline` (calling it early does nothing)."""
        if self._deadline is None or now < self._deadline:
            return
        self._deadline = None
        self.stats.timeouts += 1
        state = self._state
        if state is _S.AWAIT_REPEAT:
            # The peer did not come back with its block: repeat ours after all.
            status = self._await_status or HostStatus.NO_QUITT
            self._await_status = None
            self._state = _S.IDLE
            self._retry(now, status, eot=False)
        elif state is _S.SEND_READY:
            self._retry(now, HostStatus.NO_ENQ, eot=False)
        elif state is _S.SEND_ACK:
            self._retry(now, HostStatus.NO_QUITT, eot=True)
        elif state is _S.RECV_FRAME:
            # LSV2TIME0: the block did not end in time; the sender repeats after our NAK.
            self._frame.clear()
            self._nak(now)
        else:
            # RECV_START (LSV2TIME2 after DLE 0) and RECV_END (no EOT after DLE 1 / NAK): the
            # line is considered idle again.
            if state is _S.RECV_START:
                self._phase_failed = True  # its block may have been lost whole
            self._receive_ended(now)

    def data_to_send(self) -> bytes:
        """Bytes to write to the line now (empty if none)."""
        if not self._tx:
            return b""
        data = bytes(self._tx)
        self._tx.clear()
        if self.on_bytes is not None:
            self.on_bytes("send", data)
        return data

    def next_event(self) -> LinkEvent | None:
        """Oldest event not yet returned, or ``None``."""
        return self._events.popleft() if self._events else None

    def abandon(self, now: float) -> None:
        """Give up everything queued and end any transmission of ours with EOT."""
        if self._state in (_S.SEND_READY, _S.SEND_ACK):
            self._tx += _EOT
            self._state = _S.IDLE
            self._deadline = None
        elif self._state is _S.AWAIT_REPEAT:
            self._state = _S.IDLE
            self._deadline = None
        self._out.clear()

    # -- internals -----------------------------------------------------------------------------

    def _write(self, data: bytes) -> None:
        self._tx += data

    def _start_next(self, now: float) -> None:
        if self._state is not _S.IDLE or not self._out:
            return
        self._ack_by_answer = None
        self._out[0].tries += 1
        self._out[0].enq_again = False
        self._write(_ENQ)
        self._state = _S.SEND_READY
        self._deadline = now + self.timing.time1

    def _retry(self, now: float, status: HostStatus, *, eot: bool) -> None:
        out = self._out[0]
        out.failures.append(status)
        if eot:
            self._write(_EOT)
        self._state = _S.IDLE
        self._deadline = None
        limit = self.nak_retries if status is HostStatus.TX_ERROR else self.retries
        if out.tries > limit:
            self._out.popleft()
            self.stats.failures += 1
            if out.framed and self._last_body is None:
                # The peer may never have had it: its next telegram may repeat its last one.
                self._last_body = out.prior_body
                self._last_confirmed = out.prior_confirmed
            if not eot:
                self._write(_EOT)  # release a peer that may still wait for our frame
            cls = (
                SerialLinkTimeout
                if status in (HostStatus.NO_ENQ, HostStatus.NO_QUITT)
                else (SerialLinkError)
            )
            what = out.frame.mnemonic if out.frame is not None else "link check"
            detail = f"{what} given up after {out.tries} tries"
            if status is HostStatus.NO_ENQ and all(s is HostStatus.NO_ENQ for s in out.failures):
                detail += " (is the control on this port, at this baud rate and in LSV2 mode?)"
            self._events.append(LinkFailed(out.frame, cls(status, detail)))
        else:
            self.stats.retries += 1
        self._start_next(now)

    def _sent_ok(self, now: float, *, implicit: bool = False) -> None:
        out = self._out.popleft()
        self._state = _S.IDLE
        self._deadline = None
        if not implicit:
            self._write(_EOT)
        assert out.frame is not None
        self.stats.sent += 1
        self._last_body = None  # we spoke: the next telegram from the peer is new
        self._events.append(TelegramSent(out.frame, out.tries))

    def _give_up_ambiguous(self, body: bytes) -> None:
        """Report our telegram as failed: the peer's answer cannot confirm it (see above)."""
        out = self._out.popleft()
        self.stats.failures += 1
        self.stats.ambiguous += 1
        # Whichever it was, the peer now has our DLE 1 for ``body`` (or repeats it once more).
        self._last_body = body
        self._last_confirmed = False
        what = out.frame.mnemonic if out.frame is not None else "link check"
        detail = (
            f"{what} unconfirmed, and the peer's next telegram equals its previous one, "
            "whose DLE 1 may have been lost: cannot tell whether it arrived"
        )
        self._events.append(LinkFailed(out.frame, SerialLinkError(HostStatus.NO_QUITT, detail)))

    def _nak(self, now: float) -> None:
        self._phase_failed = True
        self._acked_last = False
        self.stats.naks_sent += 1
        self._write(_NAK)
        self._state = _S.RECV_END
        self._deadline = now + self.timing.time2

    def _yield_to_peer(self, now: float, status: HostStatus) -> None:
        """Answer the peer's ENQ while our framed telegram is unconfirmed (see the docstring).

        ``status`` is what this try failed with should no new telegram follow."""
        self._ack_by_answer = status
        self._ready(now)

    def _receive_ended(self, now: float, *, eot: bool = False) -> None:
        """The peer's transmission is over (EOT or LSV2TIME2): the line is idle again."""
        if self._acked_last:
            # An EOT right after our DLE 1 shows the peer had it; without one (LSV2TIME2) the
            # peer may still be waiting for it and repeat its telegram.
            self._acked_last = False
            # Only an EOT well inside the peer's LSV2TIME1 counts: a peer that never had our
            # DLE 1 also ends with EOT, when its LSV2TIME1 runs out (taken as ours: time1).
            self._last_confirmed = eot and now - self._acked_at < self.timing.time1 / 2
        self._state = _S.IDLE
        self._deadline = None
        status = self._ack_by_answer
        if status is not None and self._out:
            # We yielded to an "ENQ" that brought no telegram: ours was not confirmed.
            self._ack_by_answer = None
            if self._phase_failed:
                # The peer did send a block (we refused it): it holds our telegram, or this
                # is its repeat of an older one. Give it LSV2TIME1 to send its block
                # again rather than repeat ours at once: a repeat of ours reaching it while it
                # waits for DLE 1 looks like a new answer whenever answers are alike (T_OK
                # after T_OK; docs/lsv2-serial.md, "Equal telegrams in a row").
                self._await_status = status
                self._state = _S.AWAIT_REPEAT
                self._deadline = now + self.timing.time1
                return
            self._retry(now, status, eot=False)
            return
        self._start_next(now)

    def _ready(self, now: float) -> None:
        if self._acked_last:
            # A new ENQ instead of the EOT after our DLE 1: the peer may be repeating.
            self._acked_last = False
            self._last_confirmed = False
        self._phase_failed = False
        self._write(READY)
        self._state = _S.RECV_START
        self._deadline = now + self.timing.time2

    def _feed(self, data: bytes, now: float) -> None:
        i = 0
        n = len(data)
        while i < n:
            if self._state is _S.RECV_FRAME:
                i = self._feed_frame(data, i, now)
                continue
            b = data[i]
            i += 1
            if self._dle:
                if b == DLE:
                    # DLE DLE has no meaning outside a block: a repeated DLE (a gateway
                    # replaying a chunk); the pair still starts with one DLE.
                    self.stats.garbage += 1
                    continue
                self._dle = False
                self._token_dle(b, now)
            elif b == DLE:
                self._dle = True
            else:
                self._token(b, now)

    def _line_error(self, now: float) -> None:
        """A character failed its parity or framing check: its value means nothing."""
        self.stats.line_errors += 1
        if self._state is _S.RECV_FRAME:
            # Whatever it was (a body byte, the DLE of DLE ETX, the BCC), this block is not the
            # one sent. Read on to its end as usual and refuse it there.
            self._spoilt = True
            self._feed(b"\x00", now)  # stands in for the character: it keeps a BCC position
            return
        self._dle = False
        self._garbage(now)  # a handshake character nobody can read; after DLE 0: a block

    def _token(self, b: int, now: float) -> None:
        state = self._state
        if b == ENQ:
            if state is _S.AWAIT_REPEAT:
                # The peer repeats its block: a new telegram in it still confirms ours.
                self._ack_by_answer = self._await_status
                self._await_status = None
                self._ready(now)
                return
            if state is _S.SEND_READY:
                if self.role is LinkRole.CLIENT:
                    # Collision: the PC yields, takes the control's telegram, then tries again.
                    self.stats.collisions += 1
                    if self._out[0].framed:
                        # Our frame went out before and this is a retry: if the control
                        # now sends a telegram it has ours (its DLE 1 got spoilt). A late NAK
                        # with one bit changed also reads ENQ: wait for the telegram.
                        self._yield_to_peer(now, HostStatus.NO_ENQ)
                        return
                    self._out[0].tries -= 1
                    self._ready(now)
                return  # the control keeps waiting: the PC yields
            if state is _S.SEND_ACK:
                # Either the peer has moved on to a transmission of its own (it has our
                # telegram) or this is its NAK with one bit changed: its telegram decides.
                self._yield_to_peer(now, HostStatus.NO_QUITT)
                return
            self._ready(now)
            return
        if b == EOT:
            if state in (_S.RECV_START, _S.RECV_END):
                self._receive_ended(now, eot=state is _S.RECV_END)
                return
        elif b == NAK:
            if state is _S.SEND_ACK:
                self.stats.naks_received += 1
                self._out[0].unrefused -= 1  # the peer refused this frame: it does not hold it
                self._retry(now, HostStatus.TX_ERROR, eot=True)
                return
            if state is _S.SEND_READY:
                # A late answer to the block of the previous try: the peer was still reading
                # that block when our ENQ came, so took the ENQ (and any EOT) for block bytes,
                # and now waits for EOT or ENQ. Ask once more at once rather than lose this
                # try to LSV2TIME1; once per try, so a peer that NAKs every ENQ still ends.
                self.stats.naks_received += 1
                out = self._out[0]
                if not out.enq_again:
                    out.enq_again = True
                    self._write(_ENQ)
                    self._deadline = now + self.timing.time1
                return
        self._garbage(now)

    def _garbage(self, now: float) -> None:
        """Count a byte that fits no handshake; after our DLE 0 it means a block began unseen."""
        self.stats.garbage += 1
        if self._state is _S.RECV_START:
            # Perhaps the sender's DLE STX was lost or spoilt and its block is arriving: read
            # on as a block that will be refused (NAK at its DLE ETX BCC or at LSV2TIME0),
            # because it may hold ENQ or EOT bytes that must not be taken for handshake
            # characters. A DLE STX still starts a clean block (it never occurs in a body).
            self._start_frame(now, spoilt=True)

    def _token_dle(self, b: int, now: float) -> None:
        state = self._state
        if b == 0x30 and state is _S.SEND_READY:
            out = self._out[0]
            if out.frame is None:  # the link check
                self._out.popleft()
                self._state = _S.IDLE
                self._deadline = None
                self._events.append(LinkChecked())
                if self._out:
                    self._start_next(now)
                else:
                    self._write(_EOT)
                return
            self._write(out.wire)
            out.unrefused += 1
            if not out.framed:
                out.prior_body = self._last_body
                out.prior_confirmed = self._last_confirmed
            out.framed = True
            # The peer may take this telegram and answer it with one equal to its last (T_OK
            # after T_OK): that answer is new, though nothing confirmed ours yet (our DLE 1
            # may be what got lost; docs/lsv2-serial.md, "Equal telegrams in a row").
            self._last_body = None
            self._state = _S.SEND_ACK
            self._deadline = now + self.timing.time1
            return
        if b == 0x31 and state is _S.SEND_ACK:
            self._sent_ok(now)
            self._start_next(now)
            return
        if b == STX and state is _S.RECV_START:
            self._start_frame(now, spoilt=False)
            return
        self._garbage(now)

    def _start_frame(self, now: float, *, spoilt: bool) -> None:
        self._state = _S.RECV_FRAME
        self._frame.clear()
        self._scan = 0
        self._spoilt = spoilt
        self._deadline = now + self.timing.time0

    def _feed_frame(self, data: bytes, start: int, now: float) -> int:
        """Take frame bytes from ``data[start:]``; return the index after those consumed."""
        frame = self._frame
        base = len(frame)
        frame += data[start:] if start else data
        pos = self._scan
        limit = 2 * self.max_body + 8
        while True:
            j = frame.find(_DLE_B, pos)
            if j < 0 or j + 1 >= len(frame):
                self._scan = len(frame) if j < 0 else j
                if len(frame) > limit:
                    # Far longer than any telegram: lost sync; refuse and let the sender retry.
                    frame.clear()
                    self._nak(now)
                return len(data)
            nxt = frame[j + 1]
            if nxt == STX:
                # DLE STX never occurs in a stuffed body: a block starts here (the sender
                # repeats, or noise came before it). Drop what came before.
                del frame[: j + 2]
                base -= j + 2
                pos = 0
                self._spoilt = False
                continue
            if nxt != ETX:
                pos = j + 2  # DLE DLE is a data byte; any other pair spoils the block (BCC)
                continue
            if j + 2 >= len(frame):
                self._scan = j
                # The BCC is due at once; if it was lost, answer NAK before the sender's
                # LSV2TIME1 runs out rather than take its EOT for the BCC.
                end = now + self.timing.time2
                if self._deadline is None or end < self._deadline:
                    self._deadline = end
                return len(data)  # the BCC has not arrived yet
            check = frame[j + 2]
            raw = bytes(frame[:j])
            used = j + 3 - base  # bytes of this chunk that belonged to the frame
            frame.clear()
            self._scan = 0
            self._frame_done(raw, check, now)
            return start + used

    def _frame_done(self, raw: bytes, check: int, now: float) -> None:
        if self._spoilt:
            self._nak(now)  # its DLE STX never came: not a block we can trust
            return
        body = raw.replace(_DLE_DLE, _DLE_B)
        stuffed_ok = body.replace(_DLE_B, _DLE_DLE) == raw
        if not stuffed_ok or len(body) < 4 or len(body) > self.max_body or bcc(body) != check:
            self._nak(now)
            return
        if not all(0x20 <= c <= 0x7E for c in body[:4]):
            self._nak(now)  # telegram names are printable: this block is spoilt
            return
        frame = Frame(body[:4].decode("ascii"), body[4:])
        repeat = body == self._last_body
        ambiguous = False
        if self._ack_by_answer is not None and not repeat and self._out:
            out = self._out[0]
            if body == out.prior_body and not out.prior_confirmed:
                # The peer's last telegram again, and it may never have had our DLE 1 for it:
                # its repeat (then ours never arrived) or its new answer, equal to the last
                # (T_OK after T_OK). Taken for an answer, a file block the peer never read
                # was counted delivered (docs/lsv2-serial.md, "Equal telegrams in a row").
                if out.unrefused <= 0:
                    # Every frame of ours was refused with NAK: the peer never took it, so
                    # this is its repeat. Acknowledge it, pass it not on, and send ours again
                    # when the receive phase ends (``_ack_by_answer`` stays set for that).
                    repeat = True
                    self._last_body = body
                else:
                    self._ack_by_answer = None
                    ambiguous = True
            else:
                # The peer sent a new telegram after ours: it has ours (module docstring).
                self._ack_by_answer = None
                self.stats.implicit_acks += 1
                self._sent_ok(now, implicit=True)
        self._write(RECEIVED)
        self._state = _S.RECV_END
        self._deadline = now + self.timing.time2
        self._acked_last = True
        self._acked_at = now
        if ambiguous:
            self._give_up_ambiguous(body)
            return
        if self.drop_repeats and repeat:
            self.stats.repeats_dropped += 1
            return
        self._last_body = body
        self._last_confirmed = False
        self.stats.received += 1
        self._events.append(TelegramReceived(frame))


_CHAR_NAMES = {ENQ: "ENQ", EOT: "EOT", NAK: "NAK", 0x06: "ACK"}


def describe_link_bytes(data: bytes) -> str:
    """Readable rendering of link bytes for traces: ``ENQ``, ``DLE 0``, ``DLE STX``, hex."""
    parts: list[str] = []
    i = 0
    while i < len(data):
        b = data[i]
        if b == DLE and i + 1 < len(data):
            nxt = data[i + 1]
            name = {0x30: "DLE 0", 0x31: "DLE 1", STX: "DLE STX", ETX: "DLE ETX"}.get(nxt)
            if name is not None:
                parts.append(name)
                i += 2
                continue
        parts.append(_CHAR_NAMES.get(b, f"{b:02X}"))
        i += 1
    return " ".join(parts)
