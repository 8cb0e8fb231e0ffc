"""Pseudo-terminal pairs in raw mode, the test bench of every serial feature."""

from __future__ import annotations

import contextlib
import os
import tty
from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class PtyPair:
    """Both ends of a pseudo-terminal: ``master_fd`` for our side, ``slave_path`` to open."""

    master_fd: int
    slave_fd: int
    slave_path: str

    def close(self) -> None:
        for fd in (self.master_fd, self.slave_fd):
            with contextlib.suppress(OSError):  # already closed by its user
                os.close(fd)


def open_pty() -> PtyPair:
    """Open a pty pair with both ends raw (no echo, no line editing, no CR/LF mapping)."""
    master, slave = os.openpty()
    tty.setraw(master)
    tty.setraw(slave)
    return PtyPair(master, slave, os.ttyname(slave))
