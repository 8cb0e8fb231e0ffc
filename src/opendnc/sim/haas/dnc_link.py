"""A drip-feed as the virtual Haas takes it off the wire (sans-IO).

:class:`DncReceiver` cuts received bytes into blocks at any EOB byte (Setting 25 decides what
the PC sends; a control reading CR, LF or both works with every choice, empty blocks are
dropped), follows the ``%`` framing (leader bytes before the opening ``%`` are ignored, as
Setting 24 allows), and decides the flow-control bytes from the control's backlog of blocks
not yet executed: DC3 (XOFF) when it reaches ``buffer_blocks``, DC1 (XON) once it has fallen
to ``resume_blocks``. A sender that keeps writing past ``buffer_blocks + overrun_blocks``
overruns the buffer, which the front-end turns into an alarm, as lost characters do on a real
control.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

from opendnc.errors import InputError, RemoteProtocolError

XON = b"\x11"
XOFF = b"\x13"
# device-control and filler bytes that are never part of a block
_IGNORED = bytes((0x00, 0x11, 0x12, 0x13, 0x14, 0x1A))
_IGNORE_TABLE = bytes.maketrans(b"\r", b"\n")


class Framing(enum.Enum):
    """Where the stream is relative to its ``%`` lines."""

    LEADER = "leader"  # before the opening %
    PROGRAM = "program"
    ENDED = "ended"  # the closing % arrived


@dataclass(frozen=True, slots=True)
class DncLimits:
    """Buffer model of the control (in blocks) and the longest block accepted (bytes)."""

    buffer_blocks: int = 32
    resume_blocks: int = 8
    # blocks past the XOFF level before the buffer overflows; generous, because bytes the PC
    # wrote before it saw the XOFF sit in UART FIFOs, pty buffers and the virtual cable: on
    # the cable the PC's pty and the line hold up to 72 kB (docs/tape.md#virtual-fanuc), which
    # is 3,600 blocks of 20 bytes. Twice that, rounded up: a sender that starts while the
    # control is still full (a fenced feed's continuation; the DC3 went to the old server)
    # has heard no DC3 and sends on until the control's next DC1/DC3 cycle, on top of what
    # the old one left in the buffers (docs/server.md#a-fenced-drip-feed). Seen under load
    # with 2,048: such a continuation overran a control that ran far slower than the line.
    overrun_blocks: int = 8192
    max_block: int = 4096

    def __post_init__(self) -> None:
        if not 0 <= self.resume_blocks < self.buffer_blocks:
            raise InputError("the DNC resume level must be below the buffer size")


class DncReceiver:
    """Blocks out of a byte stream, and the XON/XOFF decisions of the control."""

    def __init__(self, limits: DncLimits | None = None) -> None:
        self.limits = limits or DncLimits()
        self.framing = Framing.LEADER
        self._partial = bytearray()
        self.xoff = False  # we told the sender to stop
        self.xoffs = 0
        self.xons = 0
        self.bytes = 0

    def receive_data(self, data: bytes) -> list[str]:
        """The complete blocks in ``data`` (the closing ``%`` included, then nothing more).

        Raises :class:`RemoteProtocolError` for a block longer than ``max_block``.
        """
        if self.framing is Framing.ENDED or not data:
            return []
        self.bytes += len(data)
        text = data.translate(_IGNORE_TABLE, _IGNORED)
        self._partial += text
        if b"\n" not in text:
            self._check_length(len(self._partial))
            return []
        *complete, rest = bytes(self._partial).split(b"\n")
        self._partial[:] = rest
        blocks: list[str] = []
        for raw in complete:
            self._check_length(len(raw))
            line = raw.decode("latin-1").strip()
            if not line:
                continue
            if self.framing is Framing.LEADER:
                if line == "%":
                    self.framing = Framing.PROGRAM
                continue  # leader or noise before the tape starts
            if line == "%":
                self.framing = Framing.ENDED
                self._partial.clear()
                blocks.append(line)
                break
            blocks.append(line)
        if self.framing is not Framing.ENDED:
            self._check_length(len(self._partial))
        return blocks

    def _check_length(self, size: int) -> None:
        if size > self.limits.max_block:
            self._partial.clear()
            raise RemoteProtocolError(
                f"DNC block longer than {self.limits.max_block} bytes ({size})"
            )

    def flow(self, backlog: int) -> bytes:
        """The flow-control byte to send for ``backlog`` unexecuted blocks (or ``b""``)."""
        limits = self.limits
        if not self.xoff and backlog >= limits.buffer_blocks and self.framing is not Framing.ENDED:
            self.xoff = True
            self.xoffs += 1
            return XOFF
        if self.xoff and (backlog <= limits.resume_blocks or self.framing is Framing.ENDED):
            self.xoff = False
            self.xons += 1
            return XON
        return b""

    def overrun(self, backlog: int) -> bool:
        """True when the sender ignored XOFF long enough to overflow the buffer."""
        return backlog > self.limits.buffer_blocks + self.limits.overrun_blocks
