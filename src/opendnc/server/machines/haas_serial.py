"""Haas controls on RS-232: programs by XModem (checksum mode, what a Haas speaks).

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

With ``dprnt = "serial"`` the lines the control prints on the same port are picked off while
the connector listens or asks (:mod:`opendnc.server.machines.dprnt_tap`) and handed to
:attr:`HaasSerialConnector.on_dprnt`.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable

from opendnc.errors import DncError, PeerClosed, TransportError, TransportTimeout
from opendnc.haas.listen import CapturedLine
from opendnc.haas.mdc_client import MdcClient
from opendnc.server.config import MachineConfig
from opendnc.server.machines.base import MachineStatus, Progress, Reception
from opendnc.server.machines.dprnt_tap import DprntTap, TapStream
from opendnc.server.machines.haas_ngc import mdc_status
from opendnc.server.store.models import utcnow
from opendnc.transport import ByteStream
from opendnc.transport.serial import open_stream
from opendnc.xmodem.driver import receive as xmodem_receive
from opendnc.xmodem.driver import send as xmodem_send
from opendnc.xmodem.events import Started
from opendnc.xmodem.framing import Mode
from opendnc.xmodem.haas import Eob, to_wire
from opendnc.xmodem.receiver import ReceiverConfig

__all__ = ["HaasSerialConnector"]

_EOB = {"CR": Eob.CR, "LF": Eob.LF, "CRLF": Eob.CRLF}
MDC_TIMEOUT = 1.0
"""Seconds a status query waits for its reply: a classic control answers within a few
characters' time, so a longer wait only delays the next listening window."""
DRAIN = 0.3  # seconds to read away a late reply before the port listens for XModem again


class HaasSerialConnector:
    """XModem on one serial line, kept open while the machine is connected (bytes that arrive
    between two listening windows wait in the port's buffer)."""

    listens = True

    def __init__(self, config: MachineConfig) -> None:
        self.config = config
        self._stream: ByteStream | None = None
        self._mdc: MdcClient | None = None
        self._tap: TapStream | None = None
        self._last: tuple[float, MachineStatus] | None = None  # the last MDC reading
        self.on_dprnt: Callable[[CapturedLine], None] | None = None
        """Where DPRNT lines printed on the port go (``dprnt = "serial"``); set by the server."""

    def _open(self) -> ByteStream:
        profile = self.config.profile
        return open_stream(
            self.config.serial,
            profile.baud,
            timeout=1.0,
            parity=profile.parity,
            bytesize=profile.bytesize,
            stopbits=profile.stopbits,
        )

    async def connect(self) -> None:
        """Open the port (a TCP serial server answers, a device exists)."""
        if self._stream is None:
            stream = await asyncio.to_thread(self._open)
            if self.config.dprnt == "serial" and self.on_dprnt is not None:
                stream = self._tap = TapStream(stream, DprntTap(self.on_dprnt))
            self._stream = stream
            self._mdc = (
                MdcClient.over(self._stream, timeout=MDC_TIMEOUT) if self.config.mdc else None
            )

    async def close(self) -> None:
        """Close the port."""
        stream, self._stream = self._stream, None
        self._mdc = self._tap = self._last = None
        if stream is not None:
            await asyncio.to_thread(stream.close)

    def _require(self) -> ByteStream:
        if self._stream is None:
            raise TransportError(f"{self.config.name}: port not open")
        return self._stream

    async def status(self) -> MachineStatus:
        """Available while the port opens; with ``mdc`` also program, mode and parts."""
        client = self._mdc
        if client is None:
            return MachineStatus(at=utcnow(), available=True, execution="READY")
        stream = self._require()
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
        return status

    async def send(self, name: str, data: bytes, progress: Progress) -> None:
        """Send the program by XModem in checksum mode."""
        wire = to_wire(data, _EOB[self.config.profile.eob])

        stream = self._require()
        await asyncio.to_thread(
            lambda: xmodem_send(stream, wire, mode=Mode.CHECKSUM, progress=progress)
        )

    def _tapping(self, mode: str) -> None:
        if self._tap is not None:
            self._tap.mode = mode

    async def verify(self, name: str, data: bytes) -> bool | None:
        """None: XModem's block checks are the only verification a serial Haas offers."""
        return None

    async def listen(self, seconds: float) -> Reception | None:
        """Receive one XModem transfer if the control starts one within ``seconds``."""

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
            )
            stream = self._require()
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
