"""Helpers for XModem tests over real pty pairs: a master-side stream and peer launchers.

The code under test opens the pty *slave* by path through pyserial (exactly what
``opendnc xmodem --port /dev/pts/N`` does); the peer (lrzsz, PyPI ``xmodem`` or our own engine
in a thread) sits on the master.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import random
import select
import struct
import subprocess
import termios
import time
import tty
from collections.abc import Iterator
from pathlib import Path

from opendnc.errors import PeerClosed, TransportTimeout
from opendnc.transport import SerialStream
from opendnc.transport.pty import PtyPair, open_pty
from opendnc.xmodem.driver import POLL


@contextlib.contextmanager
def pty_pair() -> Iterator[PtyPair]:
    """A raw pty pair, closed afterwards."""
    pair = open_pty()
    try:
        yield pair
    finally:
        pair.close()


def spawn_on_master(
    pair: PtyPair, args: list[str], cwd: Path | None = None
) -> subprocess.Popen[bytes]:
    """Run an lrzsz command with the pty master as its stdin and stdout."""
    return subprocess.Popen(
        args,
        stdin=pair.master_fd,
        stdout=pair.master_fd,
        stderr=subprocess.PIPE,
        cwd=cwd,
    )


def spawn_on_slave(
    pair: PtyPair, args: list[str], cwd: Path | None = None
) -> subprocess.Popen[bytes]:
    """Run an lrzsz command on the pty slave (a real tty, as on a serial port)."""
    return subprocess.Popen(
        args,
        stdin=pair.slave_fd,
        stdout=pair.slave_fd,
        stderr=subprocess.PIPE,
        cwd=cwd,
    )


def stop(proc: subprocess.Popen[bytes], timeout: float = 10.0) -> tuple[int, str]:
    """Wait for ``proc`` (kill it if it overruns) and return (exit code, stderr text)."""
    try:
        proc.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(timeout=5)
    err = ""
    if proc.stderr is not None and not proc.stderr.closed:
        err = proc.stderr.read().decode("latin-1", "replace")
        proc.stderr.close()
    return proc.returncode, err


def random_file(path: Path, size: int, seed: int) -> bytes:
    """Write ``size`` random bytes to ``path``; the last byte is never SUB (0x1A).

    XModem cannot tell trailing SUB bytes of a file from the padding of its last block, and
    our receiver strips that padding, so test files must not end in SUB.
    """
    data = bytearray(random.Random(seed).randbytes(size))
    if data and data[-1] == 0x1A:
        data[-1] = 0x41
    path.write_bytes(data)
    return bytes(data)


def assert_padded_copy(got: bytes, data: bytes, block: int) -> None:
    """``got`` is ``data`` plus the SUB padding of a last block of ``block`` bytes at most.

    lrzsz ``rx`` and PyPI ``xmodem`` keep the padding, so their output is compared this way.
    """
    assert len(got) >= len(data), f"peer wrote {len(got)} of {len(data)} bytes"
    assert got[: len(data)] == data, "peer's copy differs from the sent file"
    padding = got[len(data) :]
    assert padding == b"\x1a" * len(padding), "peer's copy has extra bytes that are not SUB"
    assert len(padding) < block
    if len(data) % 128 == 0:
        assert not padding


@contextlib.contextmanager
def peer_link(
    args: list[str], cwd: Path | None = None
) -> Iterator[tuple[SerialStream, subprocess.Popen[bytes]]]:
    """Start ``args`` on a fresh pty's master; yield (our pyserial stream on the slave, process).

    Our port is opened before the peer starts, because opening a port discards input already
    waiting in it. Our copies of the raw fds are closed once the peer has the master, so when
    the peer exits our side sees the link close. The peer is killed if it is still running.
    """
    master, slave = os.openpty()
    tty.setraw(master)
    tty.setraw(slave)
    stream = SerialStream(os.ttyname(slave), 115200, timeout=POLL)
    os.close(slave)
    proc: subprocess.Popen[bytes] | None = None
    try:
        proc = subprocess.Popen(args, stdin=master, stdout=master, stderr=subprocess.PIPE, cwd=cwd)
        os.close(master)
        master = -1
        yield stream, proc
    finally:
        if proc is not None:
            stop(proc, timeout=5)
        if master >= 0:
            os.close(master)
        stream.close()


_TIOCPKT = getattr(termios, "TIOCPKT", 0x5420)
_TIOCPKT_FLUSHREAD = 0x01


class FlushGatedMaster:
    """A pty-master stream in packet mode that holds each block until the peer has flushed.

    lrzsz ``rx`` flushes its tty input right after writing each ACK. On a real line a block
    cannot arrive that fast; on a pty it can, and is then thrown away (rx NAKs 5 s later).
    In packet mode (TIOCPKT) the master learns of every input flush on the slave
    (TIOCPKT_FLUSHREAD), so this stream delays a block write until the flush that follows
    the ACK has happened (at most ``gate`` seconds) -- modelling the line delay, nothing more.
    """

    def __init__(self, fd: int, timeout: float | None = POLL, gate: float = 0.05) -> None:
        self.fd = fd
        self.timeout = timeout
        self.gate = gate
        self.flushes = 0
        self._seen = 0
        self._buf = bytearray()
        fcntl.ioctl(fd, _TIOCPKT, struct.pack("i", 1))

    def _pull(self, timeout: float | None) -> bool:
        if not select.select([self.fd], [], [], timeout)[0]:
            return False
        try:
            packet = os.read(self.fd, 8192)
        except OSError as exc:
            raise PeerClosed(f"pty closed: {exc}") from exc
        if not packet:
            raise PeerClosed("pty closed")
        if packet[0] == 0:
            self._buf += packet[1:]
        elif packet[0] & _TIOCPKT_FLUSHREAD:
            self.flushes += 1
        return True

    def read(self, max_bytes: int) -> bytes:
        deadline = None if self.timeout is None else time.monotonic() + self.timeout
        while not self._buf:
            left = None if deadline is None else deadline - time.monotonic()
            if (left is not None and left <= 0) or not self._pull(left):
                raise TransportTimeout("no data on the pty master")
        data = bytes(self._buf[:max_bytes])
        del self._buf[:max_bytes]
        return data

    def write(self, data: bytes) -> None:
        if len(data) > 1:  # a block: wait for the flush that follows the peer's last answer
            deadline = time.monotonic() + self.gate
            while self.flushes == self._seen and (left := deadline - time.monotonic()) > 0:
                self._pull(left)
            self._seen = self.flushes
        view = memoryview(data)
        while view:
            view = view[os.write(self.fd, view) :]

    def set_timeout(self, seconds: float | None) -> None:
        self.timeout = seconds

    def close(self) -> None:
        with contextlib.suppress(OSError):
            os.close(self.fd)


@contextlib.contextmanager
def peer_on_slave(
    args: list[str], cwd: Path | None = None
) -> Iterator[tuple[FlushGatedMaster, subprocess.Popen[bytes]]]:
    """Start ``args`` on a fresh pty's slave (a real tty); yield (gated master stream, process)."""
    master, slave = os.openpty()
    tty.setraw(master)
    tty.setraw(slave)
    stream = FlushGatedMaster(master)
    proc: subprocess.Popen[bytes] | None = None
    try:
        proc = subprocess.Popen(args, stdin=slave, stdout=slave, stderr=subprocess.PIPE, cwd=cwd)
        os.close(slave)
        slave = -1
        yield stream, proc
    finally:
        if proc is not None:
            stop(proc, timeout=5)
        if slave >= 0:
            os.close(slave)
        stream.close()
