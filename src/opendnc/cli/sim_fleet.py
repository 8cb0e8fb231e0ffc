"""`opendnc sim fleet`: many virtual controls in one process."""

from __future__ import annotations

import asyncio
import signal
import tempfile
from pathlib import Path

import typer

from opendnc.atomicfile import atomic_write
from opendnc.cli.common import READY_FILE_HELP, cli_errors, console, ready_file
from opendnc.errors import InputError, TransportError


def fleet(
    tnc: int = typer.Option(2, "--tnc", help="Virtual TNCs (LSV2) to start."),
    haas: int = typer.Option(2, "--haas", help="Virtual Haas NGCs (MDC + share) to start."),
    serial_haas: int = typer.Option(
        0, "--serial-haas", help="Virtual Haas on virtual RS-232 cables (XModem, drip-feed)."
    ),
    fanuc: int = typer.Option(
        0, "--fanuc", help="Virtual Fanucs on virtual RS-232 cables (tape code, fanuc-0i)."
    ),
    mtconnect: int = typer.Option(
        0, "--mtconnect", help="Machines behind one virtual MTConnect agent (scripted cycles)."
    ),
    mtconnect_cycle: float = typer.Option(
        30.0, "--mtconnect-cycle", help="Seconds of one scripted part cycle (--mtconnect)."
    ),
    opcua: int = typer.Option(
        0, "--opcua", help="Machine tools of one virtual OPC UA server (scripted cycles)."
    ),
    opcua_servers: int = typer.Option(
        1,
        "--opcua-servers",
        help="Virtual OPC UA servers the --opcua machines are spread over (1: one gateway; "
        "as many as --opcua: one per control).",
    ),
    ftp: int = typer.Option(
        0,
        "--ftp",
        help="Controls with an FTP folder for programs (status through the MTConnect agent).",
    ),
    base_port: int = typer.Option(0, "--base-port", help="First TCP port (0 = any free ports)."),
    host: str = typer.Option("127.0.0.1", "--host", help="Address to listen on."),
    root: Path | None = typer.Option(None, "--root", help="Folder for the controls' files."),
    profile: str = typer.Option("tnc640", "--profile", help="Profile of the virtual TNCs."),
    config_out: Path | None = typer.Option(
        None, "--config-out", help="Write an `opendnc serve` configuration for these controls."
    ),
    bind: str = typer.Option("127.0.0.1:8000", "--bind", help="Server address in --config-out."),
    poll: float = typer.Option(1.0, "--poll", help="Status poll interval in --config-out."),
    ready: Path | None = typer.Option(None, "--ready-file", help=READY_FILE_HELP),
    block_rate: float = typer.Option(
        0.0, "--block-rate", help="Blocks a second each serial Haas runs (0: as fast as it can)."
    ),
    latency: float = typer.Option(
        0.0, "--latency", help="Milliseconds each virtual TNC takes to answer a telegram."
    ),
    receipts: Path | None = typer.Option(
        None, "--receipts", help="Append one JSON line per program a virtual TNC received."
    ),
) -> None:
    """Run many virtual controls at once (and write the server configuration for them)."""
    from opendnc.sim.fleet import server_config, start_fleet

    async def main(folder: Path) -> None:
        # before the ready line: a signal sent as soon as it appears must stop, not kill
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop.set)
        started = await start_fleet(
            folder,
            tnc=tnc,
            haas=haas,
            host=host,
            base_port=base_port,
            profile=profile,
            serial_haas=serial_haas,
            receipts=receipts,
            latency=latency / 1000,
            block_rate=block_rate,
            fanuc=fanuc,
            mtconnect=mtconnect,
            mtconnect_cycle=mtconnect_cycle,
            opcua=opcua,
            opcua_servers=opcua_servers,
            ftp=ftp,
        )
        try:
            if config_out is not None:
                text = server_config(started, bind=bind, poll_interval=poll)
                with atomic_write(config_out) as out:
                    out.write(text.encode())
            first, last = started.machines[0], started.machines[-1]
            console.print(
                f"fleet of {len(started.machines)} controls listening on {host} "
                f"({first.name}:{first.port} .. {last.name}:{last.port})"
                + (f", configuration in {config_out}" if config_out else ""),
                highlight=False,
                soft_wrap=True,
            )
            mark_ready()
            await stop.wait()
        finally:
            await started.close()
        console.print("stopped")

    with cli_errors(), ready_file(ready) as mark_ready:
        if min(tnc, haas, serial_haas, fanuc, mtconnect, opcua, ftp) < 0:
            raise InputError(
                "--tnc, --haas, --fanuc, --mtconnect, --opcua and --ftp count controls: 0 or more"
            )
        if mtconnect_cycle < 1:
            raise InputError("--mtconnect-cycle: at least 1 second")
        try:
            if root is not None:
                asyncio.run(main(root))
            else:
                with tempfile.TemporaryDirectory(prefix="opendnc-fleet-") as tmp:
                    asyncio.run(main(Path(tmp)))
        except OSError as exc:
            raise TransportError(f"fleet: {exc.strerror or exc}") from None
