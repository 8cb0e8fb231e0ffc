"""`opendnc sim fanuc`: run the virtual Fanuc on a serial port (a virtual cable end)."""

from __future__ import annotations

import contextlib
import signal
import threading
from pathlib import Path

import typer

from opendnc.cli.common import READY_FILE_HELP, cli_errors, ready_file
from opendnc.errors import InputError


def fanuc(
    serial: str = typer.Option(..., "--serial", help="Serial port or URL (a cable end)."),
    root: Path = typer.Option(Path("fanuc-memory"), "--root", help="Program memory folder."),
    profile: str = typer.Option("fanuc-0i", "--profile", help="Control profile it behaves as."),
    baud: int | None = typer.Option(None, "--baud", help="Baud rate (parameter 0103)."),
    code: str | None = typer.Option(None, "--code", help="iso or eia (parameter 0000 bit 1)."),
    stop_bits: int | None = typer.Option(
        None, "--stop-bits", help="1 or 2 (parameter 0101 bit 0)."
    ),
    eob: str | None = typer.Option(None, "--eob", help="Punch EOB in ISO: lf, crlf, cr, lfcrcr."),
    tv_check: bool = typer.Option(False, "--tv-check", help="TV check (parameter 0000 bit 0)."),
    param: list[str] = typer.Option(
        [], "--param", help="Set a parameter by number: 0000=3, 0101=1, 0103=11 (repeatable)."
    ),
    mode: str = typer.Option("read", "--mode", help="read, tape, idle or punch:NAME."),
    punch_back: bool = typer.Option(
        False, "--punch-back", help="Punch every program read straight back (verify a load)."
    ),
    block_rate: float = typer.Option(200.0, "--block-rate", help="Blocks per second in tape mode."),
    buffer_blocks: int = typer.Option(
        16, "--buffer-blocks", help="Tape-mode buffer (DC3 when full)."
    ),
    read_rate: float = typer.Option(
        0.0,
        "--read-rate",
        help="Characters a second READ stores (0 = as they come; DC3 when behind).",
    ),
    run: str | None = typer.Option(None, "--run", help="Run this stored program (DPRNT output)."),
    ready: Path | None = typer.Option(None, "--ready-file", help=READY_FILE_HELP),
) -> None:
    """Run a virtual Fanuc: READ stores programs, PUNCH sends them, TAPE runs a drip-feed."""
    from opendnc.sim.fanuc.control import FanucOptions, VirtualFanuc, parse_mode
    from opendnc.sim.fanuc.params import FanucParams
    from opendnc.tape.codes import Code, Eob
    from opendnc.tape.profiles import get_profile

    with cli_errors():
        prof = get_profile(profile)
        try:
            params = FanucParams(
                baud=baud or prof.baud,
                code=Code(code.lower()) if code else prof.code,
                stop_bits=stop_bits or int(prof.line_settings[2]),
                tv_check=tv_check or prof.tv_check,
                eob=Eob(eob.lower()) if eob else prof.eob,
            )
        except ValueError:
            raise InputError(f"bad --code {code!r} or --eob {eob!r}") from None
        if params.stop_bits not in (1, 2):
            raise InputError("--stop-bits is 1 or 2")
        numbers: dict[str, int] = {}
        for item in param:
            key, sep, value = item.partition("=")
            if not sep or not value.strip().isdigit():
                raise InputError(f"bad --param {item!r}: use NUMBER=VALUE, e.g. 0000=3")
            numbers[key.strip()] = int(value)
        params = FanucParams.from_numbers(numbers, params)
        if run is not None and not mode.strip().lower().startswith("idle"):
            raise InputError("--run prints on the port: use it with --mode idle")
        options = FanucOptions(
            block_rate=block_rate,
            buffer_blocks=buffer_blocks,
            punch_back=punch_back,
            resume_blocks=max(0, buffer_blocks // 4),
            read_rate=read_rate,
        )
        stop = threading.Event()
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, lambda *_: stop.set())
        sim = VirtualFanuc(
            serial,
            root,
            profile=prof,
            params=params,
            options=options,
            mode=parse_mode(mode),
            on_message=lambda text: print(text, flush=True),
        )
        shown = " ".join(f"{k}={v}" for k, v in params.numbers().items())
        print(
            f"SERIAL {serial} {params.baud} {sim.profile.line} {params.code.value.upper()}",
            flush=True,
        )
        print(f"PARAMS {shown}", flush=True)
        print(f"MODE {mode} MEMORY {root} programs={len(sim.programs())}", flush=True)
        with contextlib.suppress(KeyboardInterrupt), ready_file(ready) as mark_ready, sim:
            mark_ready()
            if run is not None:
                sim.run(run)
            stop.wait()
        print("stopped", flush=True)
