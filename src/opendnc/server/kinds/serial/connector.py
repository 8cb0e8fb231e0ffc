"""Tape-code controls on RS-232 through the tape engine (:mod:`opendnc.tape`): loads with
:func:`~opendnc.tape.serial_io.send_program` (optionally checked by the operator's punch back,
:func:`~opendnc.tape.serial_io.verify_punch`), drip-feed as the machine's explicit opt-in, and a
punch received between jobs by :func:`~opendnc.tape.serial_io.receive_record`.

Such a control reports nothing about itself. What the status says is what the server is doing
on the port: loading (the control is ready: a load runs nothing), drip-feeding (the program
runs, at the line fed), and otherwise ready while the port opens. Jobs run between status polls,
so the connector tells a change itself through ``on_status`` (the server puts it on the card).
"""

from __future__ import annotations

import asyncio
import enum
import tempfile
import threading
import time
from bisect import bisect_right
from collections.abc import Callable
from pathlib import Path

from opendnc.errors import (
    DncError,
    InputError,
    PeerClosed,
    TransferError,
    TransportError,
    TransportTimeout,
)
from opendnc.server.core.status import DripProgress, MachineStatus, Progress
from opendnc.server.kinds.connector import Reception
from opendnc.server.kinds.serial.schema import SerialMachine
from opendnc.server.store.models import utcnow
from opendnc.tape.codes import DC1, DC2, DC3, DC4
from opendnc.tape.serial_io import open_tape_port, receive_record, send_program, verify_punch
from opendnc.transport.base import PortStream

__all__ = ["Activity", "TapeConnector"]

# flow control (DC1, DC3), punch off (DC4), feed (NUL, DEL): no sign that a punch began
_NOT_PROGRAM = frozenset({0x00, DC1, DC3, DC4, 0x7F})
LINE_EVERY = 1.0  # least seconds between two status reports of a drip-feed's line


class Activity(enum.Enum):
    """What the server is doing on the port."""

    IDLE = "idle"
    LOADING = "loading"
    RUNNING = "running"  # drip-feeding: the control runs what arrives
    RECEIVING = "receiving"  # the control punches a program


class TapeConnector:
    """The tape engine on one serial line, kept open while the machine is connected (what the
    control sends between two listening windows waits in the port's buffer)."""

    listens = True

    def __init__(
        self,
        config: SerialMachine,
        *,
        on_status: Callable[[MachineStatus], None] | None = None,
    ) -> None:
        self.config = config
        self.on_status = on_status
        self._stream: PortStream | None = None
        self._activity = Activity.IDLE
        self._program = ""
        self._line = 0
        self._verified: bool | None = None
        # what the control sent while a load lingered (a punch that began then): the next
        # listen starts from it
        self._pending = b""
        self._lock = threading.Lock()  # the activity is set from the transfer's thread

    async def connect(self) -> None:
        """Open the port (a TCP serial server answers, a device exists)."""
        if self._stream is None:
            self._stream = await asyncio.to_thread(
                open_tape_port, self.config.serial, self.config.tape
            )

    async def close(self) -> None:
        """Close the port."""
        stream, self._stream = self._stream, None
        self._pending = b""
        if stream is not None:
            await asyncio.to_thread(stream.close)

    def _require(self) -> PortStream:
        if self._stream is None:
            raise TransportError(f"{self.config.name}: port not open")
        return self._stream

    async def status(self) -> MachineStatus:
        """What the server does on the port: the control itself tells nothing."""
        return self._status()

    def _status(self) -> MachineStatus:
        with self._lock:
            activity, program, line = self._activity, self._program, self._line
        if activity is Activity.RUNNING:
            return MachineStatus(
                at=utcnow(),
                available=True,
                execution="ACTIVE",
                mode="AUTOMATIC",
                native_mode="TAPE",
                program=program,
                line=line,
                message=f"drip-feeding {program}",
            )
        message = {
            Activity.LOADING: f"loading {program}",
            Activity.RECEIVING: "receiving a punch",
        }.get(activity, "")
        return MachineStatus(at=utcnow(), available=True, execution="READY", message=message)

    def _set(self, activity: Activity, program: str = "", line: int = 0) -> None:
        with self._lock:
            self._activity, self._program, self._line = activity, program, line
        if self.on_status is not None:
            self.on_status(self._status())

    async def send(self, name: str, data: bytes, progress: Progress) -> None:
        """Load the program into the control's memory (the operator selected READ); with
        ``verify = "punch"``, then wait for the punch back and compare it line by line."""
        self._verified = None
        self._set(Activity.LOADING, name)
        try:
            await asyncio.to_thread(self._send, name, data, progress)
        finally:
            self._set(Activity.IDLE)

    def _send(self, name: str, data: bytes, progress: Progress) -> None:
        stream = self._require()
        tape = self.config.tape
        keep = bytearray()
        with tempfile.TemporaryDirectory(prefix="opendnc-tape-") as tmp:
            path = Path(tmp) / name
            path.write_bytes(data)
            # a load runs nothing: send_program's safe mode stays on (it refuses a drip-feed)
            send_program(stream, path, tape, progress=progress, keep=keep)
            if self.config.verify == "punch":
                verify_punch(
                    stream,
                    path,
                    tape,
                    already=bytes(keep),
                    timeout=self.config.verify_timeout,
                )
                self._verified = True
            else:
                self._pending = bytes(keep)

    async def verify(self, name: str, data: bytes) -> bool | None:
        """True once the punch back matched (``verify = "punch"``); None otherwise."""
        verified, self._verified = self._verified, None
        return verified

    @property
    def unverified(self) -> str:
        """What a load's outcome says instead of "verified"."""
        return 'not verified (verify = "punch" compares the operator\'s punch back)'

    async def listen(self, seconds: float) -> Reception | None:
        """Receive one punched program if the control starts one within ``seconds``."""
        return await asyncio.to_thread(self._listen, seconds)

    def _listen(self, seconds: float) -> Reception | None:
        stream = _Watched(self._require(), self.config.tape.punch_dc2, self._receiving)
        already, self._pending = self._pending, b""
        if already:
            stream.saw(already)
        rest = bytearray()  # a punch that followed this one at once: the next listen's start
        try:
            record = receive_record(
                stream, self.config.tape, timeout=seconds, already=already, leftover=rest
            )
        except TransportTimeout as exc:
            if not stream.started:
                return None  # nobody punched: the usual case
            return Reception(b"", failed=str(exc))
        except TransferError as exc:
            if not stream.started and isinstance(exc.__context__, PeerClosed):
                # the port went away with nothing received: a link error, not a reception
                raise TransportError(f"{self.config.name}: the port closed") from exc
            return Reception(b"", failed=str(exc))
        except TransportError:
            raise  # the port itself failed: the machine's task reconnects
        except DncError as exc:
            # damaged characters or a record cut short: kept apart with the reason, never
            # written as if whole
            return Reception(b"", failed=str(exc))
        finally:
            if stream.started:
                self._set(Activity.IDLE)
        self._pending = bytes(rest)
        return Reception(record.text.encode("latin-1"), name=record.name)

    def _receiving(self) -> None:
        self._set(Activity.RECEIVING)

    async def fetch(self, path: str) -> bytes:
        """A tape control sends programs itself (a punch), it cannot be asked for one."""
        raise InputError(f"{self.config.name}: punch the program at the control instead")

    async def delete(self, path: str) -> None:
        """Not possible over a tape link."""
        raise InputError(f"{self.config.name}: a tape link cannot delete programs on the control")

    async def backup(self, path: str, target: Path) -> dict[str, int]:
        """Not possible over a tape link."""
        raise InputError(f"{self.config.name}: backup is for LSV2 controls")

    async def dripfeed(
        self, name: str, data: bytes, from_line: int, progress: DripProgress
    ) -> dict[str, int]:
        """Run the program as it arrives (tape/DNC mode); from a line, after the dialect's
        modal preamble. Refused unless the machine opted in with ``dripfeed = true``."""
        if not self.config.dripfeed:
            raise InputError(
                f"{self.config.name}: drip-feed is off for this machine "
                "(it runs the program: set dripfeed = true in its configuration)"
            )
        self._set(Activity.RUNNING, name, from_line)
        try:
            return await asyncio.to_thread(self._dripfeed, name, data, from_line, progress)
        finally:
            self._set(Activity.IDLE)

    def _dripfeed(
        self, name: str, data: bytes, from_line: int, progress: DripProgress
    ) -> dict[str, int]:
        stream = self._require()
        lines = data.count(b"\n") + (0 if data.endswith(b"\n") else 1)
        starts = _line_starts(data)
        skipped = starts[min(from_line, len(starts)) - 1] if from_line > 1 else 0
        feed_total = len(data) - skipped
        told = [0.0]

        def on_progress(done: int, total: int) -> None:
            # ``done``: where in the file the lines written whole end (the engine counts the
            # file, not the wire with its leader, parity and preamble) -> the first line the
            # control has not got whole, where a restart begins, and the bytes this feed took
            # from its start line to there.
            line = max(from_line, _line_at(starts, done, lines))
            progress(line, lines, max(0, done - skipped), feed_total)
            now = time.monotonic()
            if now - told[0] >= LINE_EVERY:
                told[0] = now
                self._set(Activity.RUNNING, name, line)

        with tempfile.TemporaryDirectory(prefix="opendnc-tape-") as tmp:
            path = Path(tmp) / name
            path.write_bytes(data)
            report = send_program(
                stream,
                path,
                self.config.tape,
                drip_feed=True,
                safe_mode=False,  # the machine's dripfeed = true is the opt-in to a run
                from_line=from_line,
                progress=on_progress,
            )
        return {"nbytes": report.bytes_sent, "lines": report.lines, "xoffs": report.xoffs}


def _line_starts(data: bytes) -> list[int]:
    """Where each program line (from 1) starts in ``data``."""
    starts = [0]
    at = data.find(b"\n")
    while at != -1 and at + 1 < len(data):
        starts.append(at + 1)
        at = data.find(b"\n", at + 1)
    return starts


def _line_at(starts: list[int], offset: int, lines: int) -> int:
    """The program line (from 1) that byte ``offset`` is in, at most ``lines``."""
    return min(lines, bisect_right(starts, offset))


class _Watched:
    """The port as a punch receive reads it, telling ``on_start`` once when a punch begins
    (the control's DC2, or any character but flow control and feed where it sends no DC2)."""

    def __init__(self, inner: PortStream, dc2: bool, on_start: Callable[[], None]) -> None:
        self.inner = inner
        self.dc2 = dc2
        self.on_start = on_start
        self.started = False

    def saw(self, data: bytes) -> None:
        """Look at bytes read from the port (the first punch byte starts the status)."""
        if self.started or not data:
            return
        begun = DC2 in data if self.dc2 else any((b & 0x7F) not in _NOT_PROGRAM for b in data)
        if begun:
            self.started = True
            self.on_start()

    def read(self, max_bytes: int) -> bytes:
        """Read from the port."""
        data = self.inner.read(max_bytes)
        self.saw(data)
        return data

    def read_nowait(self, max_bytes: int) -> bytes:
        """Read what is there now."""
        data = self.inner.read_nowait(max_bytes)
        self.saw(data)
        return data

    def write(self, data: bytes) -> None:
        """Write to the port."""
        self.inner.write(data)

    def drain(self) -> None:
        """Wait until written bytes left the port."""
        self.inner.drain()

    def set_timeout(self, seconds: float | None) -> None:
        """Change the port's read timeout."""
        self.inner.set_timeout(seconds)

    def close(self) -> None:
        """Close the port."""
        self.inner.close()
