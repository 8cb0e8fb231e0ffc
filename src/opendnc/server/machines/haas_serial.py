"""Haas controls on RS-232: programs by XModem (checksum mode, what a Haas speaks).

A serial port has no status to poll: the machine counts as available while its port opens.
The operator puts the control in receive mode; XModem's sender then waits for its NAK.
"""

from __future__ import annotations

import asyncio

from opendnc.server.config import MachineConfig
from opendnc.server.machines.base import MachineStatus, Progress
from opendnc.server.store.models import utcnow
from opendnc.transport import ByteStream
from opendnc.transport.serial import open_stream
from opendnc.xmodem.driver import send as xmodem_send
from opendnc.xmodem.framing import Mode
from opendnc.xmodem.haas import Eob, to_wire

__all__ = ["HaasSerialConnector"]

_EOB = {"CR": Eob.CR, "LF": Eob.LF, "CRLF": Eob.CRLF}


class HaasSerialConnector:
    """XModem sends on one serial line; the line is opened per transfer."""

    def __init__(self, config: MachineConfig) -> None:
        self.config = config

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
        """Check that the port opens (a TCP serial server answers, a device exists)."""
        await asyncio.to_thread(lambda: self._open().close())

    async def close(self) -> None:
        """Nothing stays open between transfers."""

    async def status(self) -> MachineStatus:
        """Available while the port opens; RS-232 tells nothing more without DPRNT."""
        return MachineStatus(at=utcnow(), available=True, execution="READY")

    async def send(self, name: str, data: bytes, progress: Progress) -> None:
        """Send the program by XModem in checksum mode."""
        wire = to_wire(data, _EOB[self.config.profile.eob])

        def run() -> None:
            stream = self._open()
            try:
                xmodem_send(stream, wire, mode=Mode.CHECKSUM, progress=progress)
            finally:
                stream.close()

        await asyncio.to_thread(run)

    async def verify(self, name: str, data: bytes) -> bool | None:
        """None: XModem's block checks are the only verification a serial Haas offers."""
        return None
