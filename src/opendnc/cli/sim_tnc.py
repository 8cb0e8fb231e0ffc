"""`opendnc sim tnc`: run a virtual Heidenhain control (LSV2 server)."""

from __future__ import annotations

import asyncio
import signal
import sys
import time
from collections.abc import Callable
from pathlib import Path

import typer

from opendnc.cli.common import READY_FILE_HELP, cli_errors, console, err_console, ready_file
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


def _link_tracer() -> Callable[[str], None]:
    """``--trace`` on a serial line: one stderr line per chunk of link characters."""

    def show(text: str) -> None:
        sys.stderr.write(f"{time.strftime('%H:%M:%S')} {text}\n")
        sys.stderr.flush()

    return show


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
    serial: list[str] = typer.Option(
        [],
        "--serial",
        help="Also serve serial LSV2 on this device (a cable end, a pty slave); 'pty' creates "
        "a pty and prints the path to open. Repeatable.",
    ),
    baud: int = typer.Option(57600, "--baud", help="Serial line rate (--serial)."),
    parity: str = typer.Option("E", "--parity", help="Serial parity N, E or O (--serial)."),
    bytesize: int = typer.Option(8, "--bytesize", help="Serial data bits (--serial)."),
    stopbits: float = typer.Option(1.0, "--stopbits", help="Serial stop bits (--serial)."),
    no_tcp: bool = typer.Option(False, "--no-tcp", help="Serve only the --serial lines."),
    serial_mode: str = typer.Option(
        "lsv2",
        "--serial-mode",
        help="What the --serial lines speak: lsv2, or blockwise (FE modes: programs pushed "
        "to TNC:\\ and sent on request).",
    ),
    ready: Path | None = typer.Option(None, "--ready-file", help=READY_FILE_HELP),
) -> None:
    """Serve a virtual TNC over LSV2 (TCP and/or RS-232 lines) until Ctrl-C.

    The state (files, machine parameters) lives in --root and survives restarts.
    """
    from opendnc.sim.tnc import TraceHook, get_profile, new_event_loop, serve_tnc
    from opendnc.sim.tnc.serial_front import serve_serial

    if no_tcp and not serial:
        err_console.print("[bold red]error:[/] --no-tcp needs at least one --serial line")
        raise typer.Exit(1)
    with cli_errors():
        get_profile(profile)  # an unknown one is refused with the list of profiles

    async def main() -> None:
        # SIGTERM and SIGINT (even where a background shell ignores it) end the run cleanly,
        # so the state of the control is saved to --root; installed before the ready line, so
        # a signal sent as soon as it appears is not the default (a kill)
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop.set)
        server = await serve_tnc(
            profile,
            root,
            host,
            port,
            latency=latency / 1000.0,
            trace=TraceHook() if trace else None,
            dnc_option=not no_dnc,
            listen=not no_tcp,
        )
        prof = server.control.profile
        fronts = []
        for path in serial:
            fronts.append(
                await serve_serial(
                    server,
                    path,
                    baud=baud,
                    parity=parity.upper(),
                    bytesize=bytesize,
                    stopbits=stopbits,
                    trace_link=_link_tracer() if trace else None,
                    mode=serial_mode,
                )
            )
        where = [f"{server.host}:{server.port}"] if not no_tcp else []
        where += [
            f"serial {f.path} {baud} {bytesize}{parity.upper()}{stopbits:g}"
            + (" blockwise" if f.mode == "blockwise" else "")
            for f in fronts
        ]
        console.print(
            f"virtual {prof.title} ({prof.model} {prof.nc_software}) listening on "
            f"{', '.join(where)}",
            highlight=False,
            soft_wrap=True,
        )
        console.print(f"root: {server.control.root}", highlight=False, soft_wrap=True)
        mark_ready()
        try:
            await stop.wait()
        finally:
            for front in fronts:
                await front.close()
            await server.close()
        console.print("stopped")

    with cli_errors(), ready_file(ready) as mark_ready:
        try:
            with asyncio.Runner(loop_factory=new_event_loop) as runner:
                runner.run(main())
        except OSError as exc:
            # strerror is asyncio's whole sentence; str(exc) would add "[Errno 98]" before it
            raise TransportError(f"cannot listen on {host}:{port}: {exc.strerror or exc}") from None
        except KeyboardInterrupt:
            console.print("stopped")
