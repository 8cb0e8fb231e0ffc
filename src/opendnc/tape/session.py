"""Receiving a punch (sans-IO): wait for the control's DC2, read the record, end it right.

The control drives a punch: it sends DC2 (punch on), leader, the record, trailer, DC4
(punch off). :class:`PunchReceiver` is fed what arrives and told when its :attr:`timer` ran
out; :func:`receive_steps` turns its timers into waits on a clock the driver passes in, so a
driver (blocking or asyncio, :mod:`opendnc.tape.serial_io` and :mod:`opendnc.tape.aio`) only
reads the port. A receive ends

* at the record's closing ``%`` (ISO) or ER (EIA), without waiting for the DC4;
* at DC4 or at the profile's end-of-file byte (Siemens, Fagor), or
* after ``quiet`` seconds without a character (feed and DC codes once the record started do
  not count: a noisy line must not keep it open), but only as a failure unless ``quiet_ends``
  (a capture without an end mark, such as DPRNT without PCLOS): a link cut in the middle
  of a program must never leave a file that looks whole.

Every failure is typed: :class:`~opendnc.errors.TransportTimeout` when no punch starts,
:class:`~opendnc.errors.TransferError` for a record cut short, and the reader's
:class:`~opendnc.tape.errors.TapeWireError` for damaged characters.
"""

from __future__ import annotations

import enum
from collections.abc import Callable, Generator
from dataclasses import dataclass

from opendnc.errors import TransferError, TransportTimeout
from opendnc.tape.codes import DC2, Codec
from opendnc.tape.naming import received_name
from opendnc.tape.profiles import Profile
from opendnc.tape.reader import End, ReaderConfig, TapeReader
from opendnc.xmodem.events import Timer


class State(enum.Enum):
    """Where a punch receive is."""

    WAITING = "waiting"  # for DC2 (or the first character)
    RECEIVING = "receiving"
    DONE = "done"


@dataclass(frozen=True, slots=True)
class Received:
    """A whole record: its text (LF line ends), its name if it carries one, why it ended."""

    text: str
    name: str | None
    label: tuple[str, ...]
    ended: End
    wire_bytes: int


class PunchReceiver:
    """Sans-IO receive of one punched record for ``profile``; see the module doc."""

    def __init__(
        self,
        profile: Profile,
        *,
        codec: Codec | None = None,
        start_timeout: float | None = None,
        quiet: float | None = None,
        quiet_ends: bool = False,
    ) -> None:
        self.profile = profile
        self.reader = TapeReader(
            ReaderConfig(
                codec=codec or profile.codec(),
                tv_check=profile.tv_check,
                end_at_percent=profile.end_at_percent,
                eof_char=None if profile.eof_byte is None else chr(profile.eof_byte),
            )
        )
        self.quiet = profile.quiet if quiet is None else quiet
        self.quiet_ends = quiet_ends
        self.start_timeout = start_timeout
        self.state = State.WAITING
        self.leftover = b""  # bytes after the end of the record
        self._serial = 0
        self.timer: Timer | None = None
        if start_timeout is not None:
            self.timer = Timer(self._serial, start_timeout)

    @property
    def finished(self) -> bool:
        """The record is complete."""
        return self.state is State.DONE

    def receive_data(self, data: bytes) -> None:
        """Bytes from the control."""
        if not data or self.state is State.DONE:
            return
        if self.state is State.WAITING and self.profile.punch_dc2:
            start = _find_dc2(data)
            if start < 0:
                return  # flow bytes, noise or an earlier punch's tail: not ours
            data = data[start + 1 :]
            self._start()
        reader = self.reader
        progress = reader.characters + reader.leader
        used = reader.feed(data)
        if self.state is State.WAITING and (reader.started or reader.ended):
            self._start()
        elif self.state is State.RECEIVING and reader.characters + reader.leader > progress:
            # only a character (or the leader, bounded by max_leader) shows the punch goes on:
            # filler or DC codes after the start must not keep a dead record open for ever
            self._arm(self.quiet)
        if self.reader.ended is not None:
            self.leftover = data[used:]
            self._check_end()

    def _start(self) -> None:
        self.state = State.RECEIVING
        self._arm(self.quiet)

    def _arm(self, seconds: float) -> None:
        self._serial += 1
        self.timer = Timer(self._serial, seconds)

    def timed_out(self) -> None:
        """The timer ran out without new bytes."""
        if self.state is State.WAITING:
            raise TransportTimeout(
                f"no punch from the control within {self.start_timeout:g} s "
                "(select the program and press PUNCH)"
            )
        if self.state is State.RECEIVING:
            self.reader.quiet()
            self._check_end()

    def peer_closed(self) -> None:
        """The link closed: a record not yet ended is lost."""
        if self.state is not State.DONE:
            raise TransferError(self._cut("the link closed"))

    def _cut(self, what: str) -> str:
        reader = self.reader
        return (
            f"{what} after {reader.received} bytes, in line {reader.line}, before the end "
            "of the program: nothing was written"
        )

    def _check_end(self) -> None:
        reader = self.reader
        ended = reader.ended
        if ended is End.QUIET and not self.quiet_ends:
            raise TransferError(self._cut(f"the line went quiet for {self.quiet:g} s"))
        if not reader.blocks:
            raise TransferError("the control ended the punch without sending a program")
        self.state = State.DONE
        self.timer = None

    def result(self) -> Received:
        """The record, once :attr:`finished`."""
        reader = self.reader
        assert reader.ended is not None
        assert self.finished
        return Received(
            text=reader.text(),
            name=received_name(self.profile, reader.label, reader.program),
            label=tuple(reader.label),
            ended=reader.ended,
            wire_bytes=reader.received,
        )


def _find_dc2(data: bytes) -> int:
    # DC2 has an even number of ones: the same byte with or without the ISO parity bit
    return data.find(bytes((DC2,)))


ReceiveSteps = Generator[float | None, bytes | None, Received]


def receive_steps(receiver: PunchReceiver, clock: Callable[[], float]) -> ReceiveSteps:
    """The waits of ``receiver``'s receive, for a driver that holds the port.

    Yields how long the driver may wait for the control's bytes (``None``: without limit), and
    is sent what came: the bytes, ``None`` when nothing came within that time, ``b""`` when
    the link closed. Returns the record (``StopIteration.value``); raises the receiver's errors.
    A driver may wait less than it is told and send ``None``: the timer is measured on
    ``clock``, not counted in waits.
    """
    serial, deadline = -1, float("inf")
    while not receiver.finished:
        timer = receiver.timer
        wait: float | None = None
        if timer is not None:
            if timer.serial != serial:
                serial, deadline = timer.serial, clock() + timer.seconds
            wait = deadline - clock()
            if wait <= 0:
                receiver.timed_out()
                continue
        data = yield wait
        if data is None:
            continue
        if not data:
            receiver.peer_closed()
        receiver.receive_data(data)
    return receiver.result()
