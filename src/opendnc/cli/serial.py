"""`opendnc serial send|recv|dnc|profiles`: tape-code transfers with any control's profile."""

from __future__ import annotations

import contextlib
import functools
import inspect
import typing
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from opendnc.cli.common import (
    READY_FILE_HELP,
    cli_errors,
    console,
    err_console,
    print_json,
    ready_file,
)
from opendnc.errors import InputError

if TYPE_CHECKING:
    from opendnc.tape.profiles import Profile

app = typer.Typer(
    help="Tape code over RS-232 for any control: send, receive a punch, drip-feed (DNC)."
)

PORT_HELP = "Serial device (/dev/ttyUSB0, COM3), tcp://HOST:PORT, socket://HOST:PORT, rfc2217://..."
PROFILE_HELP = "Control profile (opendnc serial profiles lists them)."


def _profile(
    name: str,
    *,
    baud: int | None = None,
    line: str | None = None,
    code: str | None = None,
    eob: str | None = None,
    flow: str | None = None,
    tv_check: bool | None = None,
    wait_dc1: bool | None = None,
    leader: int | None = None,
    punch_dc2: bool | None = None,
) -> Profile:
    from opendnc.tape.codes import Code, Eob
    from opendnc.tape.profiles import get_profile

    base = get_profile(name)
    try:
        code_value = Code(code.lower()) if code else None
        eob_value = Eob(eob.lower()) if eob else None
    except ValueError:
        raise InputError(
            f"bad --code {code!r} or --eob {eob!r}: code iso|eia, eob lf|crlf|cr|lfcrcr"
        ) from None
    if code_value is not None and code_value.value == "eia" and line is None:
        line = "8N" + base.line[2:]  # EIA is 8 bits without UART parity
    changed = base.with_changes(
        baud=baud,
        line=line,
        code=code_value,
        eob=eob_value,
        flow=flow.lower() if flow else None,
        tv_check=tv_check,
        wait_dc1=wait_dc1,
        leader=leader,
        trailer=leader,
        punch_dc2=punch_dc2,
    )
    changed.line_settings  # noqa: B018 (checks a --line before any port opens)
    return changed


# The options that change the chosen profile, by the name of the command's parameter (the same
# as _profile's keyword): (option, type, help). Each is None unless given: the profile's own.
_CHANGES: dict[str, tuple[str, type, str]] = {
    "baud": ("--baud", int, "Baud rate (default: the profile's)."),
    "line": ("--line", str, "Data bits, parity, stop bits: 7E2, 8N2, 8N1 ..."),
    "code": ("--code", str, "iso or eia (default: the profile's)."),
    "eob": ("--eob", str, "End of block: lf, crlf, cr or lfcrcr."),
    "flow": ("--flow", str, "xonxoff (DC1/DC3, done by opendnc), rtscts, none."),
    "tv_check": ("--tv-check/--no-tv-check", bool, "TV check (even blocks)."),
    "wait_dc1": ("--wait-dc1/--no-wait-dc1", bool, "Start only on the control's DC1 (its READ)."),
    "leader": ("--leader", int, "Feed characters before and after."),
    "punch_dc2": ("--punch-dc2/--no-punch-dc2", bool, "A punch starts with DC2 and ends with DC4."),
}


@dataclass(frozen=True, slots=True)
class ProfileChanges:
    """The profile-changing options a command was given (``None``: the profile's own)."""

    values: Mapping[str, Any]

    def apply(self, name: str) -> Profile:
        """Profile ``name`` with these changes (:class:`InputError` for a bad value)."""
        return _profile(name, **self.values)


NO_CHANGES = ProfileChanges({})

Command = Callable[..., None]


def with_profile_changes(*names: str) -> Callable[[Command], Command]:
    """Give a command the options of :data:`_CHANGES` named ``names``, in the place of its
    ``changes`` parameter (which receives them as one :class:`ProfileChanges`): each command
    that changes a profile states which changes it takes, and each option is defined once."""

    def wrap(command: Command) -> Command:
        hints = typing.get_type_hints(command)
        params: list[inspect.Parameter] = []
        for param in inspect.signature(command).parameters.values():
            if param.name != "changes":
                params.append(param.replace(annotation=hints[param.name]))
                continue
            for name in names:
                option, kind, text = _CHANGES[name]
                params.append(
                    param.replace(
                        name=name,
                        annotation=kind | None,
                        default=typer.Option(None, option, help=text),
                    )
                )

        @functools.wraps(command)
        def run(**kwargs: Any) -> None:
            given = {name: kwargs.pop(name) for name in names}
            command(changes=ProfileChanges(given), **kwargs)

        # typer reads the options from the signature and its annotations
        run.__signature__ = inspect.Signature(params)  # type: ignore[attr-defined]
        run.__annotations__ = {param.name: param.annotation for param in params}
        return run

    return wrap


PortOpt = typer.Option(..., "--port", "-p", help=PORT_HELP)
ProfileOpt = typer.Option("fanuc-0i", "--profile", help=PROFILE_HELP)
ChunkOpt = typer.Option(None, "--chunk", help="Bytes per write.")
JsonOpt = typer.Option(False, "--json", help="Print the result as JSON.")


@app.command("profiles")
def profiles_cmd(json_out: bool = JsonOpt) -> None:
    """List the control profiles and their settings."""
    from opendnc.tape.profiles import PROFILES

    if json_out:
        print_json([_profile_row(p) for p in PROFILES.values()])
        return
    from rich.table import Table

    table = Table("profile", "line", "code", "EOB", "flow", "DC1/DC2", "feed", "framing", "names")
    for p in PROFILES.values():
        table.add_row(
            p.name,
            f"{p.baud} {p.line}",
            p.code.value.upper() + (" TV" if p.tv_check else ""),
            p.eob.value.upper(),
            p.flow,
            f"{'DC1' if p.wait_dc1 else '-'}/{'DC2-DC4' if p.punch_dc2 else '-'}",
            f"{p.leader}/{p.trailer}",
            p.framing.value + (f" +0x{p.eof_byte:02X}" if p.eof_byte is not None else ""),
            p.naming.value,
        )
    console.print(table)


def _profile_row(p: Profile) -> dict[str, Any]:
    from opendnc.cli.common import to_jsonable

    row: dict[str, Any] = to_jsonable(p)
    row["port"] = dict(zip(("bytesize", "parity", "stopbits"), p.port_settings, strict=True))
    row["software_parity"] = p.software_parity
    row["chars_per_second"] = round(p.chars_per_second, 1)
    return row


@app.command("send")
@with_profile_changes(
    "baud", "line", "code", "eob", "flow", "tv_check", "wait_dc1", "leader", "punch_dc2"
)
def send_cmd(
    file: Path = typer.Argument(..., help="Program to send.", exists=True, dir_okay=False),
    port: str = PortOpt,
    profile: str = ProfileOpt,
    changes: ProfileChanges = NO_CHANGES,
    chunk: int | None = ChunkOpt,
    xoff_timeout: float = typer.Option(60.0, "--xoff-timeout", help="Fail if DC3 lasts longer."),
    verify: bool = typer.Option(
        False, "--verify", help="Then wait for the control to punch it back and compare."
    ),
    verify_timeout: float = typer.Option(60.0, "--verify-timeout", help="Seconds for the punch."),
    json_out: bool = JsonOpt,
) -> None:
    """Send FILE to a control reading tape (on a Fanuc: EDIT, READ; the control's DC1 starts it)."""
    from opendnc.tape.serial_io import (
        check_before_send,
        open_tape_port,
        send_program,
        verify_punch,
    )

    with cli_errors():
        prof = changes.apply(profile)
        check_before_send(file, prof)  # a program the control would refuse never opens the port
        stream = open_tape_port(port, prof)
        with contextlib.closing(stream):
            kept = bytearray()
            with _bar(f"send {file.name}", file.stat().st_size, json_out) as progress:
                report = send_program(
                    stream,
                    file,
                    prof,
                    chunk=chunk,
                    xoff_timeout=xoff_timeout,
                    keep=kept,
                    progress=progress,
                )
            result: dict[str, Any] = {"sent": report}
            if not json_out:
                _print_sent(report)
            if verify:
                err_console.print("waiting for the punch back (on the control: PUNCH)")
                record = verify_punch(
                    stream, file, prof, already=bytes(kept), timeout=verify_timeout
                )
                result["verified"] = record.name or file.name
                if not json_out:
                    console.print(f"verified: {Path(record.name or file.name).stem}")
        if json_out:
            print_json(result)


@contextlib.contextmanager
def _bar(label: str, total: int, json_out: bool) -> Iterator[Callable[[int, int], None]]:
    """A byte progress bar on stderr (none with --json); yields the engine's progress callback."""
    from rich.progress import BarColumn, DownloadColumn, Progress, TextColumn, TransferSpeedColumn

    bar = Progress(
        TextColumn(label),
        BarColumn(),
        DownloadColumn(),
        TransferSpeedColumn(),
        console=err_console,
        disable=json_out,
    )
    with bar:
        task = bar.add_task(label, total=total)
        yield lambda done, size: bar.update(task, completed=done, total=size)


def _print_sent(report: Any) -> None:
    console.print(
        f"sent {report.path.name} ({report.profile}): {report.bytes_sent} bytes, "
        f"{report.lines} blocks in {report.seconds:.2f} s; held {report.paused_seconds:.2f} s "
        f"(waiting for DC1, DC3 {report.xoffs}x)",
        highlight=False,
    )


@app.command("dnc")
@with_profile_changes("baud", "line", "code", "eob", "flow", "tv_check", "wait_dc1", "leader")
def dnc_cmd(
    file: Path = typer.Argument(..., help="Program to drip-feed.", exists=True, dir_okay=False),
    port: str = PortOpt,
    profile: str = ProfileOpt,
    from_line: int = typer.Option(
        1, "--from-line", help="Restart at this file line (the modal preamble is sent first)."
    ),
    no_retract: bool = typer.Option(False, "--no-retract", help="Preamble without the Z retract."),
    changes: ProfileChanges = NO_CHANGES,
    chunk: int | None = ChunkOpt,
    xoff_timeout: float = typer.Option(120.0, "--xoff-timeout", help="Fail if DC3 lasts longer."),
    unsafe: bool = typer.Option(False, "--unsafe", help="Required: the program runs."),
    json_out: bool = JsonOpt,
) -> None:
    """Drip-feed FILE to a control in tape/DNC mode (it runs as it arrives)."""
    from opendnc.errors import SafetyLockError
    from opendnc.tape.serial_io import check_before_send, send_program

    with cli_errors():
        if not unsafe:
            raise SafetyLockError(f"drip-feeding {file.name} (it runs on the machine)")
        prof = changes.apply(profile)
        check_before_send(file, prof, drip_feed=True)
        with _bar(f"dnc {file.name}", file.stat().st_size, json_out) as progress:
            report = send_program(
                port,
                file,
                prof,
                drip_feed=True,
                from_line=from_line,
                retract=not no_retract,
                chunk=chunk,
                xoff_timeout=xoff_timeout,
                safe_mode=not unsafe,
                progress=progress,
            )
        if json_out:
            print_json(report)
            return
        for warning in report.warnings:
            console.print(f"[yellow]warning:[/] {warning}", highlight=False)
        if report.restart is not None:
            console.print(
                f"restart at line {report.restart.line}, preamble: "
                + " | ".join(report.restart.preamble),
                highlight=False,
            )
        _print_sent(report)


@app.command("recv")
@with_profile_changes("baud", "line", "code", "tv_check", "punch_dc2")
def recv_cmd(
    out: Path = typer.Argument(..., help="Folder (named by the program) or file to write."),
    port: str = PortOpt,
    profile: str = ProfileOpt,
    changes: ProfileChanges = NO_CHANGES,
    timeout: float = typer.Option(60.0, "--timeout", help="Seconds to wait for the punch."),
    quiet: float | None = typer.Option(
        None, "--quiet", help="Seconds of silence that end the receive (default: the profile's)."
    ),
    quiet_ends: bool = typer.Option(
        False, "--quiet-ends", help="A quiet line ends the record normally (no end mark)."
    ),
    ready: Path | None = typer.Option(None, "--ready-file", help=READY_FILE_HELP),
    json_out: bool = JsonOpt,
) -> None:
    """Receive one punched program (on the control: PUNCH); nothing is written unless whole."""
    from opendnc.tape.serial_io import open_tape_port, receive_program

    with cli_errors():
        prof = changes.apply(profile)
        if not out.is_dir() and not out.parent.is_dir():
            raise InputError(f"no folder {out.parent} for {out.name}")
        # the port is open before the ready file appears: a punch after it is never lost
        stream = open_tape_port(port, prof)
        with contextlib.closing(stream), ready_file(ready) as mark_ready:
            mark_ready()
            report = receive_program(
                stream, out, prof, timeout=timeout, quiet=quiet, quiet_ends=quiet_ends
            )
        if json_out:
            print_json(report)
            return
        names = ", ".join(path.name for path in report.paths or (report.path,))
        console.print(
            f"received {names}: {report.bytes} bytes, {report.lines} lines "
            f"(ended at {report.ended})",
            highlight=False,
        )
