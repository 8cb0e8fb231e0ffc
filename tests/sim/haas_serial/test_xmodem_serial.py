"""Programs into and out of the virtual Haas by XModem, through the virtual cable."""

from __future__ import annotations

import contextlib
import os
import stat
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from opendnc.errors import TransportTimeout
from opendnc.sim.haas.serial_front import SerialMode, SerialOptions, parse_mode
from opendnc.sim.haas.serial_xmodem import XmodemQuirks, punch_bytes
from opendnc.transport.serial import SerialStream
from opendnc.xmodem.events import EotAnswer, Event
from opendnc.xmodem.files import receive_file, send_file
from opendnc.xmodem.framing import Mode
from opendnc.xmodem.haas import Eob
from opendnc.xmodem.receiver import ReceiverConfig

from .conftest import PROGRAM, Bench

FAST_NAKS = XmodemQuirks(nak_interval=0.2, start_timeout=30)


def _normalise(punched: bytes) -> bytes:
    """Undo the Haas punch conventions: the leading LF and the empty block before ``%``."""
    assert punched.startswith(b"\n%\n")
    assert punched.endswith(b"\n\n%\n")
    return punched[1:-4] + b"\n%\n"


@pytest.mark.parametrize("eob", [Eob.LF, Eob.CRLF], ids=lambda e: e.value)
def test_round_trip_byte_identical(
    bench_factory: Callable[..., Bench], tmp_path: Path, eob: Eob
) -> None:
    options = SerialOptions(baud=115200, eob=eob, mode=parse_mode("receive"), quirks=FAST_NAKS)
    bench = bench_factory(options)
    source = tmp_path / "O01000.nc"
    source.write_text(PROGRAM)
    time.sleep(0.5)  # several start requests (with their extra NAKs) are now queued
    events: list[Event] = []
    sent = send_file(
        bench.pc_path, source, mode=Mode.CHECKSUM, baud=115200, eob=eob, on_event=events.append
    )
    assert sent.eot_answer is EotAnswer.CAN  # the Haas quirk, taken as success
    bench.wait(lambda: bench.front.programs == [1000])
    assert (bench.root / "O01000.nc").read_text() == PROGRAM
    assert bench.front.messages == ["RS232 DONE"]

    bench.front.select(SerialMode.PUNCH, 1000)
    time.sleep(0.2)  # the operator's key press takes effect within a poll period
    back = tmp_path / "back.nc"
    umask = os.umask(0o027)
    try:
        got = receive_file(bench.pc_path, back, mode=Mode.CHECKSUM, baud=115200)
    finally:
        os.umask(umask)
    assert stat.S_IMODE(back.stat().st_mode) == 0o640  # not mkstemp's 0600
    raw = back.read_bytes()
    if eob is Eob.CRLF:
        assert b"\r\n" in raw
        raw = raw.replace(b"\r\n", b"\n")
    assert _normalise(raw) == PROGRAM.encode()
    assert got.program is not None
    assert got.program.number == 1000
    bench.wait(lambda: bench.front.messages == ["RS232 DONE", "RS232 DONE"])


def test_start_requests_carry_extra_naks(bench_factory: Callable[..., Bench]) -> None:
    options = SerialOptions(baud=115200, mode=parse_mode("receive"), quirks=FAST_NAKS)
    bench = bench_factory(options)
    stream = SerialStream(bench.pc_path, 115200, timeout=0.1)
    try:
        seen = b""
        deadline = time.monotonic() + 3
        while seen.count(b"\x15") < 7 and time.monotonic() < deadline:
            with contextlib.suppress(TransportTimeout):  # between two start requests
                seen += stream.read(64)
    finally:
        stream.close()
    # one NAK, then three per repeated start request (capture: one, then two more)
    assert set(seen) == {0x15}
    assert seen.count(b"\x15") >= 7


def test_bursts_of_start_naks_tolerated(
    bench_factory: Callable[..., Bench], tmp_path: Path
) -> None:
    """NAK bursts racing block 1 at 9600 baud may make it go twice; the program arrives once."""
    quirks = XmodemQuirks(nak_interval=0.05, extra_naks=5, start_timeout=30)
    bench = bench_factory(SerialOptions(baud=9600, mode=parse_mode("receive"), quirks=quirks))
    source = tmp_path / "p.nc"
    source.write_text(PROGRAM.replace("O01000", "O01001"))
    sent = send_file(bench.pc_path, source, mode=Mode.CHECKSUM, baud=9600)
    assert sent.eot_answer is EotAnswer.CAN
    bench.wait(lambda: bench.front.programs == [1001])
    assert (bench.root / "O01001.nc").read_text() == PROGRAM.replace("O01000", "O01001")


def test_plain_ack_without_quirk(bench_factory: Callable[..., Bench], tmp_path: Path) -> None:
    quirks = XmodemQuirks(nak_interval=0.2, can_after_eot=False, extra_naks=0)
    bench = bench_factory(SerialOptions(baud=115200, mode=parse_mode("receive"), quirks=quirks))
    source = tmp_path / "p.nc"
    source.write_text(PROGRAM)
    sent = send_file(bench.pc_path, source, mode=Mode.CHECKSUM, baud=115200)
    assert sent.eot_answer is EotAnswer.ACK


def test_auto_mode_stores_xmodem(bench_factory: Callable[..., Bench], tmp_path: Path) -> None:
    bench = bench_factory(SerialOptions(baud=115200, mode=parse_mode("auto"), quirks=FAST_NAKS))
    source = tmp_path / "p.nc"
    source.write_text(PROGRAM)
    send_file(bench.pc_path, source, mode=Mode.CHECKSUM, baud=115200)
    bench.wait(lambda: bench.front.programs == [1000])


def test_punch_format() -> None:
    assert punch_bytes("%\nO00001\nM30\n%\n", Eob.LF) == b"\n%\nO00001\nM30\n\n%\n"
    assert punch_bytes("%\nO00001\nM30\n%\n", Eob.CRLF) == b"\r\n%\r\nO00001\r\nM30\r\n\r\n%\r\n"


def test_parse_mode() -> None:
    from opendnc.errors import InputError

    assert parse_mode("punch:O1000").program == 1000
    assert parse_mode("DNC").mode is SerialMode.DNC
    for bad in ("punch", "punch:Ox", "dnc:1", "fly"):
        with pytest.raises(InputError):
            parse_mode(bad)


def test_punch_ignoring_the_first_nak(bench_factory: Callable[..., Bench], tmp_path: Path) -> None:
    """Capture: the control left the PC's first NAK unanswered; the receiver's repeat starts it."""
    (tmp_path / "mem").mkdir()
    (tmp_path / "mem" / "O01000.nc").write_text(PROGRAM)
    quirks = XmodemQuirks(ignore_first_nak=True, start_timeout=30)
    bench = bench_factory(SerialOptions(baud=115200, mode=parse_mode("punch:O1000"), quirks=quirks))
    config = ReceiverConfig(start_interval=0.3, crc_tries=0)
    back = tmp_path / "back.nc"
    started = time.monotonic()
    receive_file(bench.pc_path, back, mode=Mode.CHECKSUM, baud=115200, config=config)
    assert time.monotonic() - started >= 0.3  # the transfer began on the second NAK
    assert _normalise(back.read_bytes()) == PROGRAM.encode()
    bench.wait(lambda: bench.front.messages == ["RS232 DONE"])


def test_xmodem_refused_with_parity(bench_factory: Callable[..., Bench]) -> None:
    bench = bench_factory(SerialOptions(baud=115200, parity="E", mode=parse_mode("receive")))
    bench.wait(lambda: bool(bench.front.messages))
    assert bench.front.messages[0] == "RS232 ABORT XMODEM needs parity N (Setting 12)"
