"""`opendnc sim haas`: run the virtual Haas control."""

from __future__ import annotations

import asyncio
import contextlib
import signal
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import typer

from opendnc.cli.common import READY_FILE_HELP, cli_errors, err_console, ready_file
from opendnc.errors import InputError, TransportError
from opendnc.haas.mdc import ControlType
from opendnc.sim.haas.app import SimHaas, SimOptions
from opendnc.sim.haas.control import DprntDestination, HaasConfig
from opendnc.sim.haas.surface import parse_surface

if TYPE_CHECKING:
    from opendnc.sim.haas.serial_front import SerialOptions


def parse_dprnt(spec: str | None, root: Path) -> tuple[DprntDestination, int | None, Path | None]:
    """``serial`` | ``tcp:PORT`` | ``file[:PATH]`` -> destination, TCP port, file path."""
    if spec is None or spec == "none":
        return DprntDestination.NONE, None, None
    kind, _, arg = spec.partition(":")
    if kind == "serial" and not arg:
        return DprntDestination.SERIAL, None, None
    if kind == "tcp" and arg.isdigit():
        return DprntDestination.TCP, int(arg), None
    if kind == "file":
        return DprntDestination.FILE, None, Path(arg) if arg else root / "dprnt.txt"
    raise InputError(f"bad --dprnt {spec!r}: use serial, tcp:PORT or file[:PATH]")


def _trace(direction: str, data: bytes) -> None:
    arrow = "<-" if direction == "rx" else "->"
    err_console.print(f"[dim]MDC {arrow} {data!r}[/]", highlight=False)


def haas(
    model: str = typer.Option("VF-2", "--model", help="Model name Q102 reports."),
    control: str = typer.Option("ngc", "--control", help="ngc or classic (MDC framing)."),
    root: Path = typer.Option(Path("haas-memory"), "--root", help="Program memory folder."),
    serial: str | None = typer.Option(None, "--serial", help="Serial port or URL (front-end)."),
    baud: int | None = typer.Option(None, "--baud", help="Serial baud rate (Setting 11)."),
    host: str = typer.Option("127.0.0.1", "--host", help="Address to bind TCP ports to."),
    mdc_port: int = typer.Option(5051, "--mdc-port", help="MDC TCP port (0 = any free port)."),
    dprnt: str | None = typer.Option(
        None, "--dprnt", help="DPRNT destination: serial, tcp:PORT or file[:PATH]."
    ),
    surface: str | None = typer.Option(
        None,
        "--surface",
        help="Probing surface: flat:z, plane:a,b,c, sine:amp,period[,z0], "
        "wave:amp,period[,z0], bowl:depth,radius[,cx,cy[,z0]], csv:PATH (x,y,z height map).",
    ),
    block_rate: float = typer.Option(0.0, "--block-rate", help="Blocks per second (0 = max)."),
    run: int | None = typer.Option(None, "--run", help="Start this stored program (O number)."),
    serial_number: str = typer.Option("1234567", "--serial-number", help="Q100 answer."),
    strict_probe: bool = typer.Option(
        False, "--strict-probe", help="Alarm when no surface lies within the H search distance."
    ),
    probe_noise: float = typer.Option(
        1.0, "--probe-noise", help="Probe repeatability, 1 sigma in micrometres (0 = exact)."
    ),
    probe_seed: int | None = typer.Option(None, "--probe-seed", help="Seed for probe noise."),
    trace: bool = typer.Option(False, "--trace", help="Print MDC traffic on stderr."),
    serial_mode: str = typer.Option(
        "auto",
        "--serial-mode",
        help="What the serial port does: receive, punch:O<n>, dnc, dnc-xmodem, auto, idle.",
    ),
    parity: str = typer.Option("N", "--parity", help="Serial parity N, E or O (Setting 12)."),
    eob: str = typer.Option("lf", "--eob", help="EOB (Setting 25): lf, cr, crlf, crcr, lflf."),
    dnc_timeout: float = typer.Option(
        10.0, "--dnc-timeout", help="Seconds without DNC data before the link-lost alarm."
    ),
    haas_quirks: bool = typer.Option(
        True, "--haas-quirks/--no-haas-quirks", help="Extra NAKs and CAN after EOT, as a Haas does."
    ),
    punch_back: bool = typer.Option(
        False,
        "--punch-back",
        help="Punch every program received by XModem back out (an operator checking a load).",
    ),
    ready: Path | None = typer.Option(None, "--ready-file", help=READY_FILE_HELP),
) -> None:
    """Run a virtual Haas: MDC on TCP, DPRNT to TCP/file, programs from --root."""
    with cli_errors():
        try:
            control_type = ControlType(control.lower())
        except ValueError:
            raise InputError(f"bad --control {control!r}: use ngc or classic") from None
        destination, dprnt_port, dprnt_file = parse_dprnt(dprnt, root)
        wants_serial = (
            serial is not None or baud is not None or destination is DprntDestination.SERIAL
        )
        if wants_serial and serial is None:
            raise InputError("--baud / --dprnt serial need --serial PORT")
        config = HaasConfig(
            model=model,
            control=control_type,
            serial_number=serial_number,
            dprnt=destination,
            dprnt_file=str(dprnt_file or ""),
            dprnt_port=dprnt_port or 0,
            strict_probe=strict_probe,
            probe_noise_um=probe_noise,
            probe_seed=probe_seed,
            surface=parse_surface(surface) if surface else None,
        )
        options = SimOptions(
            host=host,
            mdc_port=mdc_port,
            dprnt_tcp_port=dprnt_port,
            dprnt_file=dprnt_file,
            block_rate=block_rate,
            trace=_trace if trace else None,
        )
        serial_options = _serial_options(
            serial_mode, baud or 9600, parity, eob, dnc_timeout, haas_quirks, punch_back
        )
        with contextlib.suppress(KeyboardInterrupt), ready_file(ready) as mark_ready:
            try:
                asyncio.run(
                    _serve(
                        config,
                        root,
                        options,
                        serial,
                        baud or 9600,
                        run,
                        serial_options,
                        mark_ready,
                    )
                )
            except OSError as exc:
                # a taken MDC/DPRNT port: asyncio's strerror names the address
                raise TransportError(f"virtual Haas: {exc.strerror or exc}") from None


async def _serve(
    config: HaasConfig,
    root: Path,
    options: SimOptions,
    serial: str | None,
    baud: int,
    run: int | None,
    serial_options: SerialOptions | None = None,
    mark_ready: Callable[[], None] = lambda: None,
) -> None:
    # SIGTERM and SIGINT (even where a background shell ignores it) end the run cleanly;
    # installed before the ready lines, so a signal sent as soon as they appear stops the run
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    sim = SimHaas(config, root, options)
    if options.trace is not None:
        sim.control.event_hooks.append(
            lambda event: err_console.print(f"[dim]RUN {event}[/]", highlight=False)
        )
    await sim.start()
    try:
        if serial is not None:
            # imported here: only --serial needs the front-end (and pyserial behind it)
            from opendnc.sim.haas.serial_front import start_serial

            front = await start_serial(sim, serial, baud, options.trace, serial_options)
            front.on_message = lambda text: print(text, flush=True)  # RS232 DONE / ABORT
            sim.add_front_end(front)
            print(f"SERIAL {serial} {baud}", flush=True)
        if sim.mdc is not None:
            print(f"MDC {options.host}:{sim.mdc.port}", flush=True)
        if sim.dprnt_tcp is not None:
            print(f"DPRNT tcp {options.host}:{sim.dprnt_tcp.port}", flush=True)
        if sim.dprnt_file is not None:
            print(f"DPRNT file {sim.dprnt_file.path}", flush=True)
        print(f"MEMORY {root} programs={len(sim.control.store.numbers())}", flush=True)
        mark_ready()
        if run is not None:
            if sim.dprnt_tcp is not None:
                # DPRNT lines printed before a reader connects are lost, as on the control;
                # a stop while waiting for one ends the run at once
                reader = asyncio.ensure_future(sim.dprnt_tcp.wait_reader(30.0))
                stopped = asyncio.ensure_future(stop.wait())
                await asyncio.wait({reader, stopped}, return_when=asyncio.FIRST_COMPLETED)
                for task in (reader, stopped):
                    task.cancel()
            if not stop.is_set():
                sim.control.start_program(run)
        await stop.wait()
    finally:
        await sim.close()
        print("stopped", flush=True)


def _serial_options(
    mode: str,
    baud: int,
    parity: str,
    eob: str,
    dnc_timeout: float,
    quirks: bool,
    punch_back: bool = False,
) -> SerialOptions:
    """The serial front-end's options (imported here: only --serial needs them)."""
    from opendnc.sim.haas.serial_front import SerialOptions, parse_mode
    from opendnc.sim.haas.serial_xmodem import XmodemQuirks
    from opendnc.xmodem.haas import Eob

    try:
        eob_choice = Eob(eob.lower())
    except ValueError:
        raise InputError(f"bad --eob {eob!r}: use lf, cr, crlf, crcr or lflf") from None
    if parity.upper() not in ("N", "E", "O"):
        raise InputError(f"bad --parity {parity!r}: use N, E or O")
    return SerialOptions(
        baud=baud,
        parity=parity.upper(),
        eob=eob_choice,
        mode=parse_mode(mode),
        quirks=XmodemQuirks() if quirks else XmodemQuirks(extra_naks=0, can_after_eot=False),
        dnc_timeout=dnc_timeout,
        punch_back=punch_back,
    )
