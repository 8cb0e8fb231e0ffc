"""XModem through the virtual cable with bit errors and dropped bytes.

The promise under test: every transfer either completes with a byte-identical file at the
destination, or fails with a typed error from :mod:`opendnc.errors` after its retries -- never
a silently corrupted or partial file. The cable runs fast (1 Mbaud) because the point here is
the faults, not the line rate; timeouts are shortened to match so each run takes seconds.
"""

from __future__ import annotations

import random
import subprocess
import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pytest

from opendnc.errors import DncError, TransferError
from opendnc.sim.cable import VirtualCable
from opendnc.transport import SerialStream
from opendnc.xmodem.driver import send
from opendnc.xmodem.files import receive_file
from opendnc.xmodem.framing import Mode
from opendnc.xmodem.receiver import ReceiverConfig
from opendnc.xmodem.sender import SenderConfig
from tests.peers import require_command

BAUD = 1_000_000
SUB = 0x1A
# timeouts scaled to a 1 Mbaud line (a 1K block takes ~10 ms), retries as in standard XModem
FAST_RX = ReceiverConfig(
    start_timeout=10.0,
    start_interval=0.3,
    block_timeout=1.0,
    char_timeout=0.15,
    purge_quiet=0.05,
)
FAST_TX = SenderConfig(start_timeout=10.0, ack_timeout=0.6, eot_timeout=0.3)
RUN_LIMIT = 60.0  # a run that takes longer than this is a hang


def payload(size: int, seed: int) -> bytes:
    """Random file bytes that do not end in SUB (XModem strips trailing padding)."""
    data = bytearray(random.Random(seed).randbytes(size))
    if data[-1] == SUB:
        data[-1] = 0x0A
    return bytes(data)


@dataclass
class Outcome:
    value: object = None  # Completed or the raised exception

    @property
    def ok(self) -> bool:
        return self.value is not None and not isinstance(self.value, BaseException)


def in_thread(
    target: Callable[..., object], *args: object, **kwargs: object
) -> tuple[threading.Thread, Outcome]:
    outcome = Outcome()

    def run() -> None:
        try:
            outcome.value = target(*args, **kwargs)
        except DncError as exc:
            outcome.value = exc

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread, outcome


def checksum_blind_spots(sent: bytes, got: bytes) -> list[int]:
    """Blocks that differ although their 8-bit sums agree, if that explains every difference.

    Two bit errors that cancel in the sum (+2^k in one byte, -2^k in another) pass any 8-bit
    checksum: a limit of checksum XModem itself (the Haas variant), not of an implementation.
    Returns [] when some difference is NOT of that kind (then it is an engine bug).
    """
    if len(sent) != len(got):
        return []
    blind = []
    for start in range(0, len(sent), 128):
        mine, theirs = sent[start : start + 128], got[start : start + 128]
        if mine != theirs:
            if sum(mine) % 256 != sum(theirs) % 256:
                return []
            blind.append(start // 128 + 1)
    return blind


def assert_honest_destination(
    dest: Path, data: bytes, received: Outcome, mode: Mode | None = None
) -> None:
    """Completed means identical bytes; failure means a typed error and no file at all."""
    leftovers = sorted(p.name for p in dest.parent.iterdir() if p != dest)
    assert leftovers == [], f"temporary files left behind: {leftovers}"
    if received.ok:
        got = dest.read_bytes()
        if got != data and mode is Mode.CHECKSUM and (blind := checksum_blind_spots(data, got)):
            # reproducible with the cable's seed; CRC and 1K modes have no such blind spot
            pytest.xfail(f"checksum XModem cannot see cancelling bit errors (blocks {blind})")
        assert got == data
    else:
        assert isinstance(received.value, DncError), received.value
        assert not dest.exists(), "a failed receive left a file at the destination"


def our_transfer(
    cable: VirtualCable, mode: Mode, data: bytes, dest: Path
) -> tuple[Outcome, Outcome]:
    """Our sender on side A, our receiver on side B; both must end within RUN_LIMIT."""
    tx = SerialStream(cable.path_a, BAUD, timeout=0.05)
    rx = SerialStream(cable.path_b, BAUD, timeout=0.05)
    try:
        receiver, received = in_thread(
            receive_file, rx, dest, mode=mode, config=FAST_RX, binary=True
        )
        sender, sent = in_thread(send, tx, data, mode=mode, config=FAST_TX)
        sender.join(RUN_LIMIT)
        receiver.join(RUN_LIMIT)
        assert not sender.is_alive(), "sender hung"
        assert not receiver.is_alive(), "receiver hung"
    finally:
        tx.close()
        rx.close()
    return sent, received


@pytest.mark.parametrize("mode", [Mode.CHECKSUM, Mode.CRC, Mode.ONE_K], ids=lambda m: m.name)
@pytest.mark.parametrize(
    ("ber", "drop", "seed"),
    [(1e-5, 1e-5, 1), (1e-4, 1e-4, 1), (1e-4, 1e-4, 2)],
    ids=["ber1e-5", "ber1e-4-s1", "ber1e-4-s2"],
)
def test_faulty_line_gives_identical_file_or_typed_error(
    tmp_path: Path, mode: Mode, ber: float, drop: float, seed: int
) -> None:
    data = payload(20_000 if ber >= 1e-4 else 40_000, seed)
    dest = tmp_path / "O01000.nc"
    with VirtualCable(baud=BAUD, noise=ber, drop=drop, seed=seed) as cable:
        sent, received = our_transfer(cable, mode, data, dest)
        stats = cable.stats
    assert_honest_destination(dest, data, received, mode)
    # at these rates XModem's retries recover: anything else is a finding, not noise
    assert received.ok, received.value
    assert sent.ok, sent.value
    if ber >= 1e-4:
        # the run really met faults (else it proves nothing); 20 kB at 1e-4 carries ~16 flips
        assert stats.a_to_b.corrupted + stats.a_to_b.dropped > 0, stats


@pytest.mark.parametrize("mode", [Mode.CHECKSUM, Mode.CRC, Mode.ONE_K], ids=lambda m: m.name)
def test_hopeless_line_fails_cleanly(tmp_path: Path, mode: Mode) -> None:
    """Every block is damaged: both ends give up with a typed error, nothing is written."""
    data = payload(3000, 7)
    dest = tmp_path / "O02000.nc"
    with VirtualCable(baud=BAUD, noise=3e-2, drop=1e-2, seed=3) as cable:
        sent, received = our_transfer(cable, mode, data, dest)
    assert_honest_destination(dest, data, received)
    assert isinstance(received.value, DncError), received.value
    assert isinstance(sent.value, DncError), sent.value
    assert isinstance(sent.value, TransferError) or isinstance(received.value, TransferError)


def test_lrzsz_sx_through_faulty_cable_to_our_receiver(tmp_path: Path) -> None:
    sx = require_command("sx")
    data = payload(16_000, 5)
    source = tmp_path / "src" / "O03000.nc"
    source.parent.mkdir()
    source.write_bytes(data)
    dest = tmp_path / "dst" / "O03000.nc"
    dest.parent.mkdir()
    with VirtualCable(baud=BAUD, noise=1e-4, drop=1e-5, seed=4) as cable:
        rx = SerialStream(cable.path_b, BAUD, timeout=0.05)
        try:
            receiver, received = in_thread(
                receive_file, rx, dest, mode=Mode.CRC, config=FAST_RX, binary=True
            )
            with open(cable.path_a, "r+b", buffering=0) as tty:
                proc = subprocess.run(
                    # a relative name: the current lrzsz refuses absolute paths
                    [sx, "-X", "-k", "-q", source.name],
                    stdin=tty,
                    stdout=tty,
                    stderr=subprocess.PIPE,
                    cwd=source.parent,
                    timeout=RUN_LIMIT,
                    check=False,
                )
            receiver.join(RUN_LIMIT)
            assert not receiver.is_alive(), "receiver hung"
        finally:
            rx.close()
        stats = cable.stats
    assert_honest_destination(dest, data, received)
    assert proc.returncode == 0, proc.stderr
    assert received.ok, received.value
    assert stats.a_to_b.corrupted + stats.a_to_b.dropped > 0, stats


@pytest.mark.slow
def test_our_sender_through_faulty_cable_to_lrzsz_rx(tmp_path: Path) -> None:
    rx_cmd = require_command("rx")
    # rx waits out its whole timeout (-t, at least 1 s) before it NAKs a damaged block, so
    # every fault costs a second here: a small file, and an ACK timeout longer than rx's
    data = payload(6_000, 6)
    to_rx = SenderConfig(start_timeout=10.0, ack_timeout=1.5, eot_timeout=1.5, eot_retries=1)
    with VirtualCable(baud=BAUD, noise=1e-4, drop=1e-5, seed=6) as cable:
        tx = SerialStream(cable.path_a, BAUD, timeout=0.05)
        try:
            with open(cable.path_b, "r+b", buffering=0) as tty:
                proc = subprocess.Popen(
                    [rx_cmd, "-X", "-c", "-q", "-t", "10", "O04000.nc"],
                    stdin=tty,
                    stdout=tty,
                    stderr=subprocess.PIPE,
                    cwd=tmp_path,
                )
                try:
                    sent = Outcome()
                    try:
                        sent.value = send(tx, data, mode=Mode.CRC, config=to_rx)
                    except DncError as exc:
                        sent.value = exc
                    _, rx_err = proc.communicate(timeout=RUN_LIMIT)
                finally:
                    if proc.poll() is None:
                        proc.kill()
                        proc.communicate()
        finally:
            tx.close()
        stats = cable.stats
    assert sent.ok, sent.value
    assert proc.returncode == 0, rx_err
    # rx keeps the SUB padding of the last block
    assert (tmp_path / "O04000.nc").read_bytes().rstrip(bytes([SUB])) == data
    assert stats.a_to_b.corrupted + stats.a_to_b.dropped > 0, stats
