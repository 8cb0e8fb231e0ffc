"""Helpers for XModem tests over real pty pairs: a master-side stream and peer launchers.

The code under test opens the pty *slave* by path through pyserial (exactly what
``opendnc xmodem --port /dev/pts/N`` does); the peer (lrzsz, PyPI ``xmodem`` or our own engine
in a thread) sits on the master.
"""

from __future__ import annotations

import contextlib
import os
import select
import subprocess
from collections.abc import Iterator
from pathlib import Path

from opendnc.errors import PeerClosed, TransportTimeout
from opendnc.transport.pty import PtyPair, open_pty


class FdStream:
    """A :class:`~opendnc.transport.base.ByteStream` over a raw file descriptor (pty master)."""

    def __init__(self, fd: int, timeout: float | None = 0.05) -> None:
        self.fd = fd
        self.timeout = timeout

    def read(self, max_bytes: int) -> bytes:
        ready, _, _ = select.select([self.fd], [], [], self.timeout)
        if not ready:
            raise TransportTimeout("no data on the pty master")
        try:
            data = os.read(self.fd, max_bytes)
        except OSError as exc:  # EIO once every slave holder has closed it
            raise PeerClosed(f"pty closed: {exc}") from exc
        if not data:
            raise PeerClosed("pty closed")
        return data

    def write(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            view = view[os.write(self.fd, view) :]

    def set_timeout(self, seconds: float | None) -> None:
        self.timeout = seconds

    def close(self) -> None:
        with contextlib.suppress(OSError):
            os.close(self.fd)


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
    err = proc.stderr.read().decode("latin-1", "replace") if proc.stderr else ""
    if proc.stderr:
        proc.stderr.close()
    return proc.returncode, err
