"""An XModem sender that stops dead halfway, for the tests of a receiver whose sender dies.

``python xmodem_dying_sender.py pty`` opens a pty and prints its device path;
``... tcp`` listens on 127.0.0.1 (a serial server in raw TCP mode) and prints ``tcp://...``;
``... serial PATH`` opens PATH (a virtual cable's side). It prints ``midway`` once 2 KiB went
out, then hangs in the middle of the transfer until the test kills it.
"""

from __future__ import annotations

import socket
import sys
import time

from opendnc.transport.base import ByteStream
from opendnc.transport.fd import FdStream
from opendnc.transport.pty import open_pty
from opendnc.transport.serial import SerialStream
from opendnc.xmodem.driver import send
from opendnc.xmodem.framing import Mode

PROGRAM = b"%\nO03000\n" + b"G01 X1.5 Y2.25 F36.\n" * 5000 + b"M30\n%\n"


def progress(done: int, total: int | None) -> None:
    if done >= 2048:
        print("midway", flush=True)
        time.sleep(3600)  # hung mid-transfer: only a kill ends this process


def main(kind: str, path: str = "") -> None:
    stream: ByteStream
    keep: object = None
    if kind == "pty":
        pair = open_pty()
        keep = pair  # the slave stays open here too, so the receiver may come late
        print(pair.slave_path, flush=True)
        stream = FdStream(pair.master_fd, timeout=0.05)
    elif kind == "tcp":
        listener = socket.create_server(("127.0.0.1", 0))
        print(f"tcp://127.0.0.1:{listener.getsockname()[1]}", flush=True)
        conn, _ = listener.accept()
        keep = conn
        stream = FdStream(conn.fileno(), timeout=0.05)
    else:
        print(path, flush=True)
        stream = SerialStream(path, 115200, timeout=0.05)
    send(stream, PROGRAM, mode=Mode.CHECKSUM, progress=progress)
    del keep


if __name__ == "__main__":
    main(*sys.argv[1:])
