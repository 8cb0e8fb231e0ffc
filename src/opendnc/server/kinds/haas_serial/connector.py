"""Haas controls on RS-232: programs by XModem (checksum mode, what a Haas speaks), or as
plain text with ``protocol = "text"`` in the serial profile.

A serial port has no status to poll: the machine counts as available while its port opens.
Between jobs the port listens as an XModem receiver, so a program the operator punches (or a
remote request) arrives without anyone at the PC; the receiver's start requests (NAK every
few seconds) are what a Haas waits for before it sends. To load a program the operator puts
the control in receive mode, and the control's NAK starts our sender.

With ``mdc = true`` (a classic control with Setting 143 ON) a status poll also asks Q500 and
Q104 on the same port, at most every ``mdc_interval`` seconds (3 s by default: classic controls
have frozen under fast serial polling, docs/haas.md#mdc-polling), between two listening
windows: the connector owns the port, so a query never meets an XModem transfer. A control busy
with something else (its own receive mode, a punch waiting for our NAK) does not answer; that
poll reports the execution state as unknown and the link stays up (docs/haas.md#mdc).

With ``protocol = "text"`` a load is streamed like a drip-feed (tape leader and trailer, the
profile's EOB, XON/XOFF, an optional wait for the first XON and a delay after each line), and the
port listens for a text punch between the start and end triggers instead of asking for XModem
(:mod:`opendnc.haas.textpunch`); which profile field applies to which transfer is in
docs/server.md#serial-profile.

With ``dprnt = "serial"`` the lines the control prints on the same port are picked off while
the connector listens or asks (:mod:`opendnc.server.kinds.dprnt_tap`) and handed to
:attr:`HaasSerialConnector.on_dprnt`.
"""

from __future__ import annotations

import asyncio
import tempfile
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

from opendnc.errors import DncError, InputError, PeerClosed, TransportError, TransportTimeout
from opendnc.haas.dnc import DncConfig, FeedPosition, Flow, stream_program
from opendnc.haas.listen import CapturedLine
from opendnc.haas.mdc_client import MdcClient
from opendnc.haas.textpunch import TextCapture
from opendnc.server.core.status import DripProgress, MachineStatus, Progress
from opendnc.server.kinds.base import SerialProfile
from opendnc.server.kinds.connector import JobCancelled, Reception, StreamWrapper
from opendnc.server.kinds.dprnt_tap import DprntTap, TapStream
from opendnc.server.kinds.haas_ngc.connector import mdc_status
from opendnc.server.kinds.haas_serial.schema import HaasSerialMachine
from opendnc.server.store.models import utcnow
from opendnc.transport import ByteStream, PortStream, open_stream
from opendnc.xmodem.driver import receive as xmodem_receive
from opendnc.xmodem.driver import send as xmodem_send
from opendnc.xmodem.events import Started
from opendnc.xmodem.framing import Mode
from opendnc.xmodem.haas import Eob, to_wire
from opendnc.xmodem.receiver import ReceiverConfig

__all__ = ["ControlSilent", "HaasSerialConnector", "SilenceGuard"]

TEXT_READ = 0.05  # seconds a text-punch listener waits per read (its clock for the idle timeout)
MDC_TIMEOUT = 1.0
"""Seconds a status query waits for its reply: a classic control answers within a few
characters' time, so a longer wait only delays the next listening window."""
DRAIN = 0.3  # seconds to read away a late reply before the port listens for XModem again
XMODEM_SILENCE_FLOOR = 11.0
"""Least silence that ends an XModem load: an XModem receiver asks for a lost block again
after 10 s, and that wait is no sign of a dead control."""


class ControlSilent(TransportError):
    """The control stopped answering in the middle of a transfer."""


class SilenceGuard(StreamWrapper):
    """A :class:`ByteStream` that raises :class:`ControlSilent` once the control, having
    answered at least once, has been silent for ``limit`` seconds (reads keep their timeout;
    the check runs in the reading thread, so nothing closes the port under a read)."""

    def __init__(self, inner: ByteStream, limit: float, machine: str) -> None:
        super().__init__(inner)
        self.limit = limit
        self.machine = machine
        self.heard: float | None = None  # when the control last said anything

    def read(self, max_bytes: int) -> bytes:
        """Read; raise :class:`ControlSilent` after ``limit`` seconds without a byte."""
        try:
            data = self.inner.read(max_bytes)
        except TransportTimeout:
            self._check()
            raise
        if data:
            self.heard = time.monotonic()
        else:
            self._check()
        return data

    def _check(self) -> None:
        if self.heard is not None and time.monotonic() - self.heard >= self.limit:
            raise ControlSilent(
                f"{self.machine}: the control went silent for {self.limit:g} s mid-transfer"
            )


class HaasSerialConnector:
    """XModem on one serial line, kept open while the machine is connected (bytes that arrive
    between two listening windows wait in the port's buffer)."""

    listens = True
    resumes_feeds = True
    """A drip-feed stopped by a fence says where it stopped, and one can continue from there
    (docs/server.md#a-fenced-drip-feed)."""

    def __init__(
        self,
        config: HaasSerialMachine,
        *,
        quiet_after_break: float = 30.0,
        on_dprnt: Callable[[CapturedLine], None] | None = None,
    ) -> None:
        self.config = config
        self._stream: PortStream | None = None
        # After a drip-feed breaks, the control still waits in DNC mode for the rest of the
        # program: the listener's start requests (NAK) would reach it as program input and
        # keep it from timing out into its DNC-link alarm. The port stays silent this long.
        self.quiet_after_break = quiet_after_break
        self._quiet_until = 0.0
        self._mdc: MdcClient | None = None
        self._tap: TapStream | None = None  # the port as listening and MDC read it
        self._last: tuple[float, MachineStatus] | None = None  # the last MDC reading
        # What the last drip-feed left the control in, when it did not end well: a broken
        # feed is an alarm with its text, a cancelled one a stopped program. A control
        # without MDC never says otherwise, so it stands until the next transfer (a load, a
        # drip-feed, a punch); with MDC, until the control answers again.
        self._left: MachineStatus | None = None
        self.on_dprnt = on_dprnt
        """Where DPRNT lines printed on the port go (``dprnt = "serial"``)."""

    def _open(self) -> PortStream:
        profile = self.config.profile
        return open_stream(
            self.config.serial,
            profile.baud,
            timeout=1.0,
            parity=profile.parity,
            bytesize=profile.bytesize,
            stopbits=profile.stopbits,
            # XModem is binary: XON/XOFF must not be taken out of the data by the port;
            # a drip-feed handles the control's DC1/DC3 itself.
            flow="rtscts" if profile.flow == "rtscts" else "none",
        )

    async def connect(self) -> None:
        """Open the port (a TCP serial server answers, a device exists)."""
        if self._stream is None:
            self._stream = await asyncio.to_thread(self._open)
            if self.config.dprnt == "serial" and self.on_dprnt is not None:
                self._tap = TapStream(self._stream, DprntTap(self.on_dprnt))
            if self.config.mdc:
                self._mdc = MdcClient.over(self._reader(), timeout=MDC_TIMEOUT)

    async def close(self) -> None:
        """Close the port."""
        stream, self._stream = self._stream, None
        self._mdc = self._tap = self._last = None
        if stream is not None:
            await asyncio.to_thread(stream.close)

    @property
    def silence_limit(self) -> float:
        """Seconds of silence from the control that end a load under way: the profile's
        ``idle_timeout``, but never less than :data:`XMODEM_SILENCE_FLOOR` (the receiver's own
        NAK after a lost block must still get through)."""
        return max(self.config.profile.idle_timeout, XMODEM_SILENCE_FLOOR)

    def _require(self) -> PortStream:
        if self._stream is None:
            raise TransportError(f"{self.config.name}: port not open")
        return self._stream

    def _reader(self) -> ByteStream:
        """The port as listening and MDC read it (through the DPRNT tap when there is one)."""
        return self._tap if self._tap is not None else self._require()

    def _tapping(self, mode: str) -> None:
        if self._tap is not None:
            self._tap.mode = mode

    async def status(self) -> MachineStatus:
        """Available while the port opens; with ``mdc`` also program, mode and parts."""
        client = self._mdc
        if self._left is not None and (client is None or time.monotonic() < self._quiet_until):
            return replace(self._left, at=utcnow())
        if client is None:
            # The port is open, but without MDC the control tells nothing of what it does:
            # its execution is unknown (UNAVAILABLE), not READY (docs/server.md#machine-status).
            return MachineStatus(at=utcnow(), available=True)
        if time.monotonic() < self._quiet_until:
            # Not asked (a query would reach a control still waiting in DNC mode as program
            # input): its state is not known, and the status says so rather than READY.
            return MachineStatus(
                at=utcnow(),
                available=True,
                message="not asked for its state after a broken drip-feed "
                f"(quiet for {self.quiet_after_break:g} s)",
            )
        stream = self._reader()
        last = self._last
        if last is not None and time.monotonic() - last[0] < self.config.mdc_interval:
            return last[1]  # paced: a classic control is not asked more often than this

        def poll() -> MachineStatus:
            self._tapping("mdc")
            try:
                return mdc_status(client.query(500), client.query(104), None)
            except TransportTimeout as exc:
                # busy with something else: the port is fine, the state unknown this time
                _drain(stream)
                return MachineStatus(at=utcnow(), available=True, message=str(exc))
            finally:
                self._tapping("off")
                stream.set_timeout(1.0)

        status = await asyncio.to_thread(poll)
        self._last = (time.monotonic(), status)
        if status.execution != "UNAVAILABLE":
            self._left = None  # the control answered: its own word from now on
        elif self._left is not None:
            return replace(self._left, at=utcnow())
        return status

    async def send(self, name: str, data: bytes, progress: Progress) -> None:
        """Send the program by XModem in checksum mode, or as plain text."""
        profile = self.config.profile
        if profile.protocol == "text":
            # A load into memory: the control stores the program, it runs nothing, so no
            # drip-feed opt-in is needed (the operator selected receive on the control).
            await asyncio.to_thread(self._stream_text, name, data, 1, progress)
            return
        # XModem frames and acknowledges every block: leader, trailer, line delay and the wait
        # for XON are plain-text matters (docs/server.md#serial-profile); the EOB applies.
        wire = to_wire(data, eob(profile))

        # A control that dies mid-load would otherwise be waited for block after block
        # (10 retries of 15 s); silent this long once the load is under way, the job ends.
        stream = SilenceGuard(self._require(), self.silence_limit, self.config.name)
        await asyncio.to_thread(
            lambda: xmodem_send(stream, wire, mode=Mode.CHECKSUM, progress=progress)
        )
        self._left = None  # the control took a program: it is out of the broken feed

    async def verify(self, name: str, data: bytes) -> bool | None:
        """None: XModem's block checks are the only verification a serial Haas offers."""
        return None

    @property
    def unverified(self) -> str:
        """What a load's outcome says instead of "verified" (docs/xmodem.md#end-to-end-checks):
        checksum XModem lets two cancelling bit errors through, and the control cannot be
        asked for the program; the operator's punch back (`opendnc haas verify`) can check."""
        if self.config.profile.protocol == "text":
            return "not verified (plain text has no check)"
        return "not verified (checksum mode only)"

    async def listen(self, seconds: float) -> Reception | None:
        """Receive one XModem transfer (or text punch) if the control starts one within
        ``seconds``."""
        if time.monotonic() < self._quiet_until:
            await asyncio.sleep(seconds)
            return None
        reception = await self._listen(seconds)
        if reception is not None and not reception.failed:
            self._left = None  # the operator punched: the control is out of the broken feed
        return reception

    async def _listen(self, seconds: float) -> Reception | None:
        if self.config.profile.protocol == "text":
            return await asyncio.to_thread(self._listen_text, seconds)

        def run() -> Reception | None:
            parts: list[bytes] = []
            started = False

            def on_event(event: object) -> None:
                nonlocal started
                started = started or isinstance(event, Started)

            config = ReceiverConfig(
                start_timeout=seconds,
                start_interval=min(3.0, seconds),
                fold_eob_checksum=True,  # Haas sums blocks with its EOB folded to LF
                cancel_when_idle=False,  # the next window listens again
                text_check=True,  # a block that is no NC text is asked for again
            )
            stream = self._reader()
            self._tapping("listen")
            try:
                xmodem_receive(
                    stream, parts.append, mode=Mode.CHECKSUM, config=config, on_event=on_event
                )
            except TransportTimeout:
                if not started:
                    return None  # nobody sent anything: the usual case
                return Reception(b"".join(parts), failed="the sender went silent")
            except DncError as exc:
                if not started and not parts:
                    return None
                return Reception(b"".join(parts), failed=str(exc))
            finally:
                self._tapping("off")
            return Reception(b"".join(parts))

        return await asyncio.to_thread(run)

    async def fetch(self, path: str) -> bytes:
        """A serial Haas sends programs itself (a punch), it cannot be asked for one."""
        raise InputError(f"{self.config.name}: punch the program at the control instead")

    async def delete(self, path: str) -> None:
        """Not possible over RS-232."""
        raise InputError(f"{self.config.name}: RS-232 cannot delete programs on the control")

    async def backup(self, path: str, target: Path) -> dict[str, int]:
        """Not possible over RS-232."""
        raise InputError(f"{self.config.name}: backup is for LSV2 controls")

    async def dripfeed(
        self,
        name: str,
        data: bytes,
        from_line: int,
        progress: DripProgress,
        *,
        resume: FeedPosition | None = None,
        stopped: Callable[[FeedPosition | None], None] | None = None,
        waiting: Callable[[], None] | None = None,
    ) -> dict[str, int]:
        """Stream the program with XON/XOFF (the control's DC3 stops us within a chunk);
        from a line, with the modal-state preamble of :mod:`opendnc.haas.modal`; or, with
        ``resume``, the rest of a fenced feed from its exact position. ``stopped`` is told
        where a feed that ends with an error stopped (None: not exactly known); ``waiting``
        is asked whenever the feed waits for the control and may raise to stop it there."""
        if not self.config.dripfeed:
            raise InputError(
                f"{self.config.name}: drip-feed is off for this machine "
                "(it runs the program: set dripfeed = true in its configuration)"
            )
        lines = data.count(b"\n") + (0 if data.endswith(b"\n") else 1)
        if resume is not None:
            from_line = data.count(b"\n", 0, resume.offset) + 1
            skipped = resume.offset
        else:
            skipped = _line_offset(data, from_line)

        feed_total = len(data) - skipped
        reached = [from_line]
        self._left = None
        # Where the last report was, so every report counts only the new bytes' line ends (a
        # count from the start each time is quadratic in the program, and drip-fed programs
        # are the big ones).
        seen = [0, 0]  # bytes consumed, line ends among them

        def on_progress(done: int, total: int | None) -> None:
            # File bytes written whole -> the first line the control has not got whole, where
            # a restart begins (lines before from_line count as done: they were skipped, not
            # sent; the leader of a restart reports nothing of the file yet), and the bytes
            # this feed took to get there.
            if done < seen[0]:
                seen[:] = [0, 0]
            seen[1] += data.count(b"\n", seen[0], done)
            seen[0] = done
            reached[0] = max(from_line, seen[1] + 1)
            progress(reached[0], lines, max(0, done - skipped), feed_total)

        try:
            # the machine's dripfeed = true is the opt-in to a run
            counts = await asyncio.to_thread(
                self._stream_text, name, data, from_line, on_progress, resume, stopped, waiting
            )
        except BaseException as exc:
            self._quiet_until = time.monotonic() + self.quiet_after_break
            self._left = _after_feed(name, reached[0], lines, exc)
            raise
        finally:
            self._last = None  # the reading from before the feed is stale: ask afresh
        # The control has the whole program (its closing %): it waits for nothing more, so a
        # completed restart ends the quiet of the break before it (docs/server.md#drip-feed).
        self._quiet_until = 0.0
        return counts

    def _stream_text(
        self,
        name: str,
        data: bytes,
        from_line: int,
        progress: Progress,
        resume: FeedPosition | None = None,
        stopped: Callable[[FeedPosition | None], None] | None = None,
        waiting: Callable[[], None] | None = None,
    ) -> dict[str, int]:
        """Plain text out, as the profile says (a drip-feed or a text load)."""
        stream = self._require()
        with tempfile.TemporaryDirectory(prefix="opendnc-dnc-") as tmp:
            path = Path(tmp) / name
            path.write_bytes(data)
            report = stream_program(
                stream,
                path,
                from_line=from_line,
                config=text_config(self.config.profile),
                safe_mode=False,  # callers decide: a load runs nothing, a drip-feed is opted in
                progress=progress,
                resume=resume,
                stopped=stopped,
                waiting=waiting,
            )
        return {"nbytes": report.bytes_sent, "lines": report.lines, "xoffs": report.xoffs}

    def _listen_text(self, seconds: float) -> Reception | None:
        """Wait up to ``seconds`` for a text punch to start; once it has, read it to its end
        trigger however long it takes, or fail after the profile's idle timeout."""
        profile = self.config.profile
        capture = TextCapture(
            profile.start_trigger.encode("latin-1"),
            profile.end_trigger.encode("latin-1"),
            eob(profile),
        )
        stream = self._reader()
        stream.set_timeout(TEXT_READ)
        deadline = time.monotonic() + seconds
        heard = time.monotonic()
        try:
            while not capture.done:
                try:
                    data = stream.read(4096)
                except TransportTimeout:
                    data = b""
                except PeerClosed:
                    if not capture.started:
                        raise
                    return Reception(capture.program(), failed="the line closed mid-punch")
                now = time.monotonic()
                if data:
                    capture.feed(data)
                    heard = now
                if not capture.started:
                    if now >= deadline:
                        return None
                elif now - heard >= profile.idle_timeout:
                    capture.quiet(profile.idle_timeout)
        finally:
            stream.set_timeout(1.0)
        return Reception(capture.program(), failed=capture.failed)


def _after_feed(name: str, line: int, lines: int, exc: BaseException) -> MachineStatus | None:
    """What a drip-feed that ended with ``exc`` at ``line`` left the control in: a person's
    cancel stopped the program (stopped); anything else broke it (an alarm, with why). A
    server that stops says nothing of the control (None)."""
    if isinstance(exc, asyncio.CancelledError | KeyboardInterrupt | SystemExit):
        return None
    where = f"at line {line} of {lines}"
    if isinstance(exc, JobCancelled):
        return MachineStatus(
            at=utcnow(),
            available=True,
            execution="INTERRUPTED",
            program=name,
            message=f"drip-feed of {name} cancelled {where}",
        )
    reason = str(exc) or type(exc).__name__
    return MachineStatus(
        at=utcnow(),
        available=True,
        execution="INTERRUPTED",
        program=name,
        errors=(f"Drip-feed of {name} broke {where}: {reason}"[:200],),
    )


def eob(profile: SerialProfile) -> Eob:
    """The profile's end of block (Haas Setting 25)."""
    return Eob[profile.eob]


def text_config(profile: SerialProfile) -> DncConfig:
    """How plain text goes out on this port: the profile's flow, EOB, leader and trailer,
    line delay and wait for the first XON (docs/server.md#serial-profile)."""
    return DncConfig(
        flow=Flow(profile.flow),
        eob=eob(profile),
        wait_for_xon=profile.wait_for_xon,
        leader=profile.leader_bytes(),
        trailer=profile.trailer_bytes(),
        line_delay=profile.line_delay,
    )


def _line_offset(data: bytes, line: int) -> int:
    """Where program line ``line`` (from 1, lines ending in LF) starts in ``data``."""
    offset = 0
    for _ in range(line - 1):
        offset = data.find(b"\n", offset) + 1
        if offset == 0:
            return len(data)
    return offset


def _drain(stream: ByteStream) -> None:
    """Read away what arrives within :data:`DRAIN` (a late reply's STX must not reach the
    XModem receiver of the next listening window, where it would look like a block)."""
    stream.set_timeout(0.05)
    deadline = time.monotonic() + DRAIN
    while time.monotonic() < deadline:
        try:
            stream.read(4096)
        except TransportTimeout:
            continue
        except PeerClosed:
            return
