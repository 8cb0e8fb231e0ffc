"""PyPI ``xmodem`` as a peer process: ``python -m tests.interop.xmodem_pypi_peer send|recv``.

Runs with the pty master as stdin/stdout (fd 0 and 1) so the peer has its own interpreter
(no GIL shared with the code under test) and can be killed if it hangs.

    python -m tests.interop.xmodem_pypi_peer send MODE FILE
    python -m tests.interop.xmodem_pypi_peer recv MODE FILE

MODE is checksum, crc or 1k. Exit status 0 on success, 1 on failure.
"""

from __future__ import annotations

import os
import select
import sys
import time

import xmodem


def _getc(size: int, timeout: float = 1) -> bytes | None:
    """Return exactly ``size`` bytes, or None if they did not arrive within ``timeout``."""
    data = b""
    deadline = time.monotonic() + timeout
    while len(data) < size:
        left = deadline - time.monotonic()
        if left <= 0 or not select.select([0], [], [], left)[0]:
            return None
        try:
            chunk = os.read(0, size - len(data))
        except OSError:
            return None
        if not chunk:
            return None
        data += chunk
    return data


def _putc(data: bytes, timeout: float = 1) -> int:
    view = memoryview(data)
    while view:
        view = view[os.write(1, view) :]
    return len(data)


def main(argv: list[str]) -> int:
    """Run one transfer; return the exit status."""
    action, mode, path = argv
    modem = xmodem.XMODEM(_getc, _putc, mode="xmodem1k" if mode == "1k" else "xmodem")
    if action == "send":
        with open(path, "rb") as stream:
            ok = modem.send(stream, retry=16, timeout=10, quiet=True)
        return 0 if ok else 1
    with open(path, "wb") as stream:
        size = modem.recv(stream, crc_mode=0 if mode == "checksum" else 1, retry=16, timeout=10)
    return 0 if size is not None else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
