"""A byte stream over file descriptors that are already open: a tty, a pty end, a pipe pair.

This is how ``sx``/``rx`` hold a serial line (the port as stdin and stdout, opened and set up
by whoever started them), and how a test or benchmark hands a pty end to an endpoint process.
Line settings are left alone: the opener sets speed and raw mode.
"""

from __future__ import annotations

import contextlib
import os
import select
import time

from opendnc.errors import PeerClosed, TransportError, TransportTimeout
from opendnc.transport.spin import DEFAULT_WINDOW, BusyPoll


class FdStream:
    """A :class:`~opendnc.transport.base.ByteStream` over ``read_fd`` and ``write_fd``.

    ``FdStream(fd)`` reads and writes one descriptor (a pty end); ``FdStream(0, 1)`` is the
    ``sx``/``rx`` arrangement, the line on stdin and stdout.

    The read side is switched to non-blocking for the stream's life (and back on
    :meth:`close`), so a read is one ``read()`` when data is waiting and ``poll()`` plus
    ``read()`` otherwise. Reads busy-poll for up to ``busy_poll`` seconds while answers keep
    coming that fast (:mod:`opendnc.transport.spin`; 0 turns it off). The descriptors are not
    closed by :meth:`close`; they belong to whoever opened them.
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
        self._was_blocking = os.get_blocking(read_fd)
        os.set_blocking(read_fd, False)
        self._poller = select.poll()
        self._poller.register(read_fd, select.POLLIN)
        self._spin = BusyPoll(busy_poll)
        self._closed = False

    def read(self, max_bytes: int) -> bytes:
        # when not spinning, poll first: a read that finds nothing raises, which costs more
        return self._spin.read(
            lambda: self._try_read(max_bytes), lambda: self._wait_read(max_bytes)
        )

    def _try_read(self, max_bytes: int) -> bytes | None:
        """One non-blocking read: None while nothing is there."""
        try:
            data = os.read(self.read_fd, max_bytes)
        except BlockingIOError:
            return None
        except OSError as exc:
            # EIO: the other end of a pty is gone, the way a tty reports a hang-up
            raise PeerClosed(f"fd {self.read_fd}: {exc.strerror or exc}") from exc
        if not data:
            raise PeerClosed(f"fd {self.read_fd}: end of file")
        return data

    def _wait_read(self, max_bytes: int) -> bytes:
        timeout = self.timeout
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            left = None if deadline is None else max(deadline - time.monotonic(), 0.0)
            ms = None if left is None else int(left * 1000) + (left * 1000 % 1 > 0)
            if not self._poller.poll(ms):
                if deadline is not None and time.monotonic() >= deadline:
                    raise TransportTimeout(f"no data on fd {self.read_fd}")
                continue
            data = self._try_read(max_bytes)
            if data is not None:
                return data

    def write(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            try:
                view = view[os.write(self.write_fd, view) :]
            except BlockingIOError:
                # stdin and stdout are often one tty, so our O_NONBLOCK is the writer's too
                self._wait_writable()
            except OSError as exc:
                raise TransportError(f"write to fd {self.write_fd} failed: {exc}") from exc

    def _wait_writable(self) -> None:
        waiter = select.poll()
        waiter.register(self.write_fd, select.POLLOUT)
        limit = None if self.timeout is None else max(1, int(self.timeout * 1000))
        if not waiter.poll(limit):
            raise TransportTimeout(f"fd {self.write_fd} takes no data")

    def set_timeout(self, seconds: float | None) -> None:
        self.timeout = seconds

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            with contextlib.suppress(OSError):
                os.set_blocking(self.read_fd, self._was_blocking)
