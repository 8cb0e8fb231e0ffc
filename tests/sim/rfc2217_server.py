"""A one-connection RFC 2217 serial server for tests: pyserial's ``PortManager`` over a device.

    python -m tests.sim.rfc2217_server DEVICE

Opens DEVICE with pyserial, listens on a free loopback port, prints ``listening PORT`` and
serves one client at a time until killed: what the client sends goes to the device (after the
Telnet / RFC 2217 layer took its commands out, such as the baud rate and parity, which
``PortManager`` applies to the device), what the device sends goes back escaped. This plays a
networked serial device server in RFC 2217 mode (docs/ports.md).
"""

from __future__ import annotations

import select
import socket
import sys
import termios

import serial
import serial.rfc2217


class _Connection:
    """What ``PortManager`` writes its Telnet answers to."""

    def __init__(self, sock: socket.socket) -> None:
        self.sock = sock

    def write(self, data: bytes) -> None:
        self.sock.sendall(data)


class _LinePort(serial.Serial):  # type: ignore[misc]
    """The device, minus modem lines: a pty (the virtual cable's end) has none, and the
    client's RTS/DTR settings and modem-state queries would fail there with ENOTTY."""

    def _update_rts_state(self) -> None:
        pass

    def _update_dtr_state(self) -> None:
        pass

    @property
    def cts(self) -> bool:
        return True

    @property
    def dsr(self) -> bool:
        return True

    @property
    def ri(self) -> bool:
        return False

    @property
    def cd(self) -> bool:
        return True

    def _reconfigure_port(self, force_update: bool = False) -> None:
        # A pty refuses parity (EINVAL); it carries no parity bit anyway (the cable counts it
        # in its timing). Keep the parity asked for, so the client is told it was applied.
        try:
            super()._reconfigure_port(force_update)
        except termios.error:
            parity, self._parity = self._parity, serial.PARITY_NONE
            try:
                super()._reconfigure_port(force_update)
            finally:
                self._parity = parity


def serve(device: str) -> None:
    port = _LinePort(device, baudrate=57600, timeout=0)
    with socket.create_server(("127.0.0.1", 0)) as server:
        print(f"listening {server.getsockname()[1]}", flush=True)
        while True:
            conn, _ = server.accept()
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            manager = serial.rfc2217.PortManager(port, _Connection(conn))
            applied = (port.baudrate, port.bytesize, port.parity, port.stopbits)
            try:
                while True:
                    ready, _, _ = select.select([conn, port.fileno()], [], [], 0.5)
                    if port.fileno() in ready:
                        data = port.read(port.in_waiting or 1)
                        if data:
                            conn.sendall(b"".join(manager.escape(data)))
                    if conn in ready:
                        data = conn.recv(4096)
                        if not data:
                            break
                        port.write(b"".join(manager.filter(data)))
                        now = (port.baudrate, port.bytesize, port.parity, port.stopbits)
                        if now != applied:
                            applied = now
                            print("settings {} {}{}{}".format(*now), flush=True)
                    manager.check_modem_lines()
            except OSError as exc:  # the client left, or the device refused a setting
                print(f"connection ended: {exc!r}", file=sys.stderr, flush=True)
            finally:
                conn.close()


if __name__ == "__main__":
    serve(sys.argv[1])
