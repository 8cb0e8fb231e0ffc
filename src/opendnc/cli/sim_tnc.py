"""`opendnc sim tnc`: run a virtual Heidenhain control (LSV2 server)."""

from __future__ import annotations

import asyncio
import signal
from pathlib import Path

import typer

from opendnc.cli.common import cli_errors, console, err_console
from opendnc.errors import TransportError

#: The simulator's profiles, named here so `--help` does not load the simulator (a test keeps
#: this equal to opendnc.sim.tnc.PROFILES).
PROFILE_NAMES = (
    "tnc640",
    "tnc620",
    "tnc320",
    "tnc7",
    "itnc530",
    "tnc426",
    "cncpilot640",
    "manualplus620",
)


def tnc(
    profile: str = typer.Option(
        "tnc640", "--profile", help=f"Control family: {', '.join(PROFILE_NAMES)}."
    ),
    root: Path | None = typer.Option(
        None, "--root", help="Folder holding the drives (default: a fresh programming station)."
    ),
    host: str = typer.Option("127.0.0.1", "--host", help="Address to listen on."),
    port: int = typer.Option(19000, "--port", help="TCP port (0 = any free port)."),
    latency: float = typer.Option(0.0, "--latency", help="Delay per telegram in milliseconds."),
    trace: bool = typer.Option(False, "--trace", help="Print every telegram (hex and decoded)."),
    no_dnc: bool = typer.Option(False, "--no-dnc-option", help="Machine without the DNC option."),
) -> None:
    """Serve a virtual TNC over LSV2 until Ctrl-C.

    The state (files, machine parameters) lives in --root and survives restarts.
    """
    from opendnc.sim.tnc import PROFILES, TraceHook, new_event_loop, serve_tnc

    if profile.lower() not in PROFILES:
        err_console.print(f"[bold red]error:[/] unknown profile {profile!r}")
        raise typer.Exit(1)

    async def main() -> None:
        server = await serve_tnc(
            profile,
            root,
            host,
            port,
            latency=latency / 1000.0,
            trace=TraceHook() if trace else None,
            dnc_option=not no_dnc,
        )
        prof = server.control.profile
        console.print(
            f"virtual {prof.title} ({prof.model} {prof.nc_software}) listening on "
            f"{server.host}:{server.port}",
            highlight=False,
            soft_wrap=True,
        )
        console.print(f"root: {server.control.root}", highlight=False, soft_wrap=True)
        # SIGTERM and SIGINT (even where a background shell ignores it) end the run cleanly,
        # so the state of the control is saved to --root.
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop.set)
        try:
            await stop.wait()
        finally:
            await server.close()
        console.print("stopped")

    with cli_errors():
        try:
            with asyncio.Runner(loop_factory=new_event_loop) as runner:
                runner.run(main())
        except OSError as exc:
            # strerror is asyncio's whole sentence; str(exc) would add "[Errno 98]" before it
            raise TransportError(f"cannot listen on {host}:{port}: {exc.strerror or exc}") from None
        except KeyboardInterrupt:
            console.print("stopped")
