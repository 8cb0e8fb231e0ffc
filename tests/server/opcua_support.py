"""A virtual OPC UA server on an event loop of its own thread, and self-signed certificates
for it and for the DNC server's client: the two talk OPC UA over loopback sockets."""

from __future__ import annotations

import asyncio
import ipaddress
import threading
import time
from collections.abc import Callable, Coroutine, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from tests.peers import require_module

require_module("asyncua")

from asyncua.crypto import cert_gen  # noqa: E402
from cryptography import x509  # noqa: E402
from cryptography.hazmat.primitives.serialization import Encoding  # noqa: E402
from cryptography.x509.oid import ExtendedKeyUsageOID  # noqa: E402

from opendnc.sim.opcua.machine import ScriptedMachineTool  # noqa: E402
from opendnc.sim.opcua.server import VirtualOpcuaServer  # noqa: E402

Step = Callable[[ScriptedMachineTool], Coroutine[Any, Any, object]]


def self_signed(folder: Path, name: str, uri: str, use: ExtendedKeyUsageOID) -> tuple[Path, Path]:
    """A key (PEM) and a self-signed application certificate (DER) for ``uri``."""
    key = cert_gen.generate_private_key()
    cert = cert_gen.generate_self_signed_app_certificate(
        key,
        name,
        {"organizationName": "opendnc tests"},
        [x509.UniformResourceIdentifier(uri), x509.DNSName("localhost"),
         x509.IPAddress(ipaddress.ip_address("127.0.0.1"))],
        [use],
    )  # fmt: skip
    key_path, cert_path = folder / f"{name}.pem", folder / f"{name}.der"
    key_path.write_bytes(cert_gen.dump_private_key_as_pem(key))
    cert_path.write_bytes(cert.public_bytes(Encoding.DER))
    return cert_path, key_path


class ServerThread:
    """A :class:`VirtualOpcuaServer` served from a loop in a thread of its own."""

    def __init__(self, names: list[str], **options: Any) -> None:
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()
        self.server = VirtualOpcuaServer(names, **options)
        self.run(self.server.start)
        self.machines = {n: ScriptedMachineTool(self.server.machines[n]) for n in names}

    def run(self, make: Callable[[], Coroutine[Any, Any, Any]]) -> Any:
        """Run a coroutine on the server's loop and wait for it."""
        return asyncio.run_coroutine_threadsafe(make(), self.loop).result(60)

    def step(self, name: str, action: Step) -> float:
        """Do one scripted step on machine ``name``; the monotonic time it was done."""
        machine = self.machines[name]
        self.run(lambda: action(machine))
        return time.monotonic()

    def stop(self) -> None:
        self.run(self.server.close)
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(10)
        self.loop.close()


@contextmanager
def server_thread(names: list[str], **options: Any) -> Iterator[ServerThread]:
    server = ServerThread(names, **options)
    try:
        yield server
    finally:
        server.stop()
