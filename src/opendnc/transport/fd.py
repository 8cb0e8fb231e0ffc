"""A byte stream over file descriptors that are already open: a tty, a pty end, a pipe pair.

This is how ``sx``/``rx`` hold a serial line (the port as stdin and stdout, opened and set up
by whoever started them), and how a test or benchmark hands a pty end to an endpoint process.
Line settings and file flags are left alone: the opener sets speed and raw mode.
"""

from __future__ import annotations

import errno
import math
import os
import select

from opendnc.errors import PeerClosed, TransportError, TransportTimeout
from opendnc.transport.spin import DEFAULT_WINDOW, BusyPoll

# errors that mean the other end is gone: a pty whose other side closed (EIO), a socket
_HANG_UP = {errno.EIO, errno.ECONNRESET, errno.EPIPE}


class FdStream:
    """A :class:`~opendnc.transport.base.ByteStream` over ``read_fd`` and ``write_fd``.

    ``FdStream(fd)`` reads and writes one descriptor (a pty end); ``FdStream(0, 1)`` is the
    ``sx``/``rx`` arrangement, the line on stdin and stdout. POSIX only (``poll()``): Windows
    programs open ports with :func:`opendnc.transport.open_stream`.

    A read waits in ``poll()`` and only then reads, so it works on blocking and non-blocking
    descriptors alike and never waits longer than its timeout. Reads busy-poll for up to
    ``busy_poll`` seconds while answers keep coming that fast (:mod:`opendnc.transport.spin`;
    0 turns it off). Writes block until the line takes the data, as on a serial port with
    flow control. The descriptors belong to whoever opened them; :meth:`close` leaves them
    open.
    """

    def __init__(
        self,
        read_fd: int,
        write_fd: int | None = None,
        *,
        timeout: float | None = 1.0,
        busy_poll: float = DEFAULT_WINDOW,
    ) -> None:
        self.read_fd = read_fd
        self.write_fd = read_fd if write_fd is None else write_fd
        self.timeout = timeout
        self._poller = select.poll()
        self._poller.register(read_fd, select.POLLIN)
        self._spin = BusyPoll(busy_poll)

    def read(self, max_bytes: int) -> bytes:
        return self._spin.read(
            lambda: self._read_if_ready(max_bytes, 0), lambda: self._wait_read(max_bytes)
        )

    def read_nowait(self, max_bytes: int) -> bytes:
        """What has already arrived (up to ``max_bytes``), ``b""`` if nothing; never waits."""
        return self._read_if_ready(max_bytes, 0) or b""

    def _read_if_ready(self, max_bytes: int, wait_ms: int | None) -> bytes | None:
        """Wait up to ``wait_ms`` for input, then read it; None if none came."""
        if not self._poller.poll(wait_ms):
            return None
        try:
            data = os.read(self.read_fd, max_bytes)
        except BlockingIOError:
            return None  # another reader of this descriptor was quicker
        except OSError as exc:
            if exc.errno in _HANG_UP:
                raise PeerClosed(f"fd {self.read_fd}: {exc.strerror}") from exc
            raise TransportError(f"read from fd {self.read_fd} failed: {exc}") from exc
        if not data:
            raise PeerClosed(f"fd {self.read_fd}: end of file")
        return data

    def _wait_read(self, max_bytes: int) -> bytes:
        timeout = self.timeout
        if timeout is None:
            while (data := self._read_if_ready(max_bytes, None)) is None:
                pass
            return data
        # poll() counts whole milliseconds: round up, so the wait is never shorter
        data = self._read_if_ready(max_bytes, max(0, math.ceil(timeout * 1000)))
        if data is None:
            raise TransportTimeout(f"no data on fd {self.read_fd} within {timeout:g} s")
        return data

    def write(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            try:
                view = view[os.write(self.write_fd, view) :]
            except BlockingIOError:
                self._wait_writable()  # the opener made the descriptor non-blocking
            except OSError as exc:
                if exc.errno in _HANG_UP:
                    raise PeerClosed(f"fd {self.write_fd}: {exc.strerror}") from exc
                raise TransportError(f"write to fd {self.write_fd} failed: {exc}") from exc

    def _wait_writable(self) -> None:
        waiter = select.poll()
        waiter.register(self.write_fd, select.POLLOUT)
        limit = None if self.timeout is None else max(1, int(self.timeout * 1000))
        if not waiter.poll(limit):
            raise TransportTimeout(f"fd {self.write_fd} takes no data")

    def drain(self) -> None:
        """Wait until a tty has sent what was written (pipes and sockets: nothing to wait for)."""
        if not os.isatty(self.write_fd):
            return
        import termios  # only a tty gets here, and ttys are POSIX

        try:
            termios.tcdrain(self.write_fd)
        except termios.error as exc:
            raise TransportError(f"drain of fd {self.write_fd} failed: {exc}") from exc

    def set_timeout(self, seconds: float | None) -> None:
        self.timeout = seconds

    def close(self) -> None:
        """Nothing to release: the descriptors stay open for their owner."""
