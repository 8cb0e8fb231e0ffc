"""`opendnc sim opcua`: a virtual OPC UA server with umati machine-tool objects."""

from __future__ import annotations

import asyncio
import signal
from pathlib import Path

import typer

from opendnc.cli.common import READY_FILE_HELP, cli_errors, console, ready_file
from opendnc.errors import InputError, TransportError


def opcua(
    port: int = typer.Option(4840, "--port", help="TCP port (0 = any free port)."),
    host: str = typer.Option("127.0.0.1", "--host", help="Address to listen on."),
    machines: int = typer.Option(1, "--machines", help="Machine tools under Objects/Machines."),
    cycle: float = typer.Option(30.0, "--cycle", help="Seconds of one scripted part cycle."),
    certificate: Path | None = typer.Option(
        None, "--certificate", help="Server certificate (DER): adds Basic256Sha256 endpoints."
    ),
    private_key: Path | None = typer.Option(None, "--private-key", help="Its private key (PEM)."),
    ready: Path | None = typer.Option(None, "--ready-file", help=READY_FILE_HELP),
) -> None:
    """Run a virtual OPC UA server whose machine tools run scripted part cycles."""
    from opendnc.sim.opcua.machine import ScriptedMachineTool, run_cycles
    from opendnc.sim.opcua.server import VirtualOpcuaServer

    async def main() -> None:
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop.set)
        names = [f"opc-{i + 1}" for i in range(machines)]
        server = VirtualOpcuaServer(
            names, host=host, port=port, certificate=certificate, private_key=private_key
        )
        await server.start()
        cycles = [
            asyncio.create_task(run_cycles(ScriptedMachineTool(server.machines[n]), cycle))
            for n in names
        ]
        try:
            console.print(
                f"virtual OPC UA server on {server.url} (machines {', '.join(names)} "
                "under Objects/Machines)",
                highlight=False,
                soft_wrap=True,
            )
            mark_ready()
            await stop.wait()
        finally:
            for task in cycles:
                task.cancel()
            await asyncio.gather(*cycles, return_exceptions=True)
            await server.close()
        console.print("stopped")

    with cli_errors(), ready_file(ready) as mark_ready:
        if not 1 <= machines <= 1000:
            raise InputError("--machines: 1 to 1000")
        if cycle < 1:
            raise InputError("--cycle: at least 1 second")
        if (certificate is None) != (private_key is None):
            raise InputError("--certificate and --private-key go together")
        try:
            asyncio.run(main())
        except OSError as exc:
            raise TransportError(f"opcua: {exc.strerror or exc}") from None
