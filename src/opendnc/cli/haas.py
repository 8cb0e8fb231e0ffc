"""`opendnc haas` commands: MDC queries, macro variables, Net Share push.

Sub-groups live in their own Typer apps (``macro``, ``share``); a new command is added with
``@app.command("name")`` in this module or in a module that imports :data:`app`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import re
from pathlib import Path
from typing import TYPE_CHECKING

import typer

from opendnc.cli.common import cli_errors, console, err_console, print_json
from opendnc.errors import ControlRefused, InputError
from opendnc.haas.mdc import Refused, reply_name

if TYPE_CHECKING:  # clients and progress bars load with the command that uses them
    from rich.progress import Progress, ProgressColumn

    from opendnc.haas.dnc import DncConfig
    from opendnc.haas.mdc_client import MdcClient
    from opendnc.haas.verify import VerifyResult
    from opendnc.transport.base import ByteStream

# MDC port (Setting 143): opendnc.haas.mdc_client.DEFAULT_PORT, without importing the client
DEFAULT_PORT = 5051

app = typer.Typer(
    help="Haas controls: MDC queries, macro variables, Net Share, load checks.",
    no_args_is_help=True,
)
macro_app = typer.Typer(help="Read or write macro variables over MDC.", no_args_is_help=True)
share_app = typer.Typer(help="Haas Net Share (SMB or a mounted folder).", no_args_is_help=True)
app.add_typer(macro_app, name="macro")
app.add_typer(share_app, name="share")

HostOpt = typer.Option("127.0.0.1", "--host", "-H", help="Control address.")
PortOpt = typer.Option(
    str(DEFAULT_PORT),
    "--port",
    "-p",
    help="MDC TCP port (NGC Setting 143), or a serial port / URL (classic, Setting 143 ON).",
)
BaudOpt = typer.Option(9600, "--baud", help="Baud rate when --port is a serial port.")
TimeoutOpt = typer.Option(3.0, "--timeout", help="Seconds to wait for each reply.")
JsonOpt = typer.Option(False, "--json", help="Print the parsed reply as JSON.")
ResultJsonOpt = typer.Option(False, "--json", help="Print the result as JSON.")


class Rejected(ControlRefused):
    """An MDC query answered with ``?`` / ``UNKNOWN`` (no numeric code on this protocol)."""

    def __init__(self, what: str, answer: str) -> None:
        super().__init__(0, answer, context=what)

    def __str__(self) -> str:
        return f"the control rejected {self.context} (it answered {self.text!r})"


def mdc_client(
    host: str,
    port: str,
    baud: int,
    timeout: float,
    *,
    safe_mode: bool = True,
    allow_any_variable: bool = False,
) -> MdcClient:
    """A TCP client when ``port`` is a number, else a serial one on that device or URL."""
    from opendnc.haas.mdc_client import MdcClient  # loads with the command that uses it

    if port.isdigit():
        return MdcClient(
            host,
            int(port),
            timeout=timeout,
            safe_mode=safe_mode,
            allow_any_variable=allow_any_variable,
        )
    return MdcClient.open_serial(
        port, baud, timeout=timeout, safe_mode=safe_mode, allow_any_variable=allow_any_variable
    )


def parse_code(code: str) -> int:
    """``Q500``, ``?Q500`` or ``500`` -> 500."""
    match = re.fullmatch(r"\??[Qq]?(\d{1,3})", code.strip())
    if match is None:
        raise InputError(f"bad Q code {code!r}: use e.g. Q500")
    return int(match.group(1))


@app.command("q")
def q(
    code: str = typer.Argument(..., help="Q command, e.g. Q500 (Q600 takes a variable)."),
    var: int | None = typer.Argument(None, help="Variable number for Q600."),
    host: str = HostOpt,
    port: str = PortOpt,
    baud: int = BaudOpt,
    timeout: float = TimeoutOpt,
    json_out: bool = JsonOpt,
) -> None:
    """Send one ?Q command and print the reply."""

    with cli_errors():
        number = parse_code(code)
        if number == 600 and var is None:
            raise InputError("Q600 needs a variable number, e.g. `opendnc haas q Q600 5223`")
        with mdc_client(host, port, baud, timeout) as client:
            reply = client.query(number, var)
        if isinstance(reply, Refused):
            # "?" (NGC) or UNKNOWN (classic): a reply, but no answer; scripts must see it fail
            what = f"Q{number:03d}" + (f" {var}" if var is not None else "")
            raise Rejected(what, reply.text)
        if json_out:
            print_json(
                {
                    "command": f"Q{number:03d}",
                    "type": type(reply).__name__,
                    "name": reply_name(reply),
                    "raw": reply.to_payload(),
                    "fields": reply,
                }
            )
        else:
            console.print(reply.to_payload(), highlight=False)


def _hms(seconds: int | None) -> str:
    if seconds is None:
        return "-"
    return f"{seconds // 3600}:{seconds % 3600 // 60:02d}:{seconds % 60:02d}"


@app.command("status")
def status(
    host: str = HostOpt,
    port: str = PortOpt,
    baud: int = BaudOpt,
    timeout: float = TimeoutOpt,
    json_out: bool = JsonOpt,
) -> None:
    """One readable summary from all documented Q commands."""
    from rich.table import Table

    with cli_errors():
        with mdc_client(host, port, baud, timeout) as client:
            summary = client.status()
        if json_out:
            print_json(summary)
            return
        table = Table(
            show_header=False,
            title=f"Haas {summary.model or ''} at {host + ':' + port if port.isdigit() else port}",
        )
        rows = [
            ("Serial number", summary.serial),
            ("Software", summary.software),
            ("Mode", summary.mode),
            ("Program", summary.program),
            ("Status", summary.status),
            ("Parts (M30 #1 / #2)", f"{summary.m30_counter_1} / {summary.m30_counter_2}"),
            ("Tool in use", summary.tool),
            ("Tool changes", summary.tool_changes),
            ("Power-on time", _hms(summary.power_on_seconds)),
            ("Cutting time", _hms(summary.cutting_seconds)),
            (
                "Last / previous cycle",
                f"{_hms(summary.last_cycle_seconds)} / {_hms(summary.previous_cycle_seconds)}",
            ),
        ]
        for label, value in rows:
            table.add_row(label, "-" if value is None else str(value))
        console.print(table)


@macro_app.command("get")
def macro_get(
    var: int = typer.Argument(..., help="Macro variable number, e.g. 5223."),
    host: str = HostOpt,
    port: str = PortOpt,
    baud: int = BaudOpt,
    timeout: float = TimeoutOpt,
    json_out: bool = JsonOpt,
) -> None:
    """Read a macro variable (?Q600)."""

    with cli_errors():
        with mdc_client(host, port, baud, timeout) as client:
            value = client.macro_get(var)
        if json_out:
            print_json({"var": var, "value": value})
        else:
            console.print(f"#{var} = {value:g}", highlight=False)


# ignore_unknown_options lets a negative VALUE (`set 5223 -1.5`) through as an argument
@macro_app.command("set", context_settings={"ignore_unknown_options": True})
def macro_set(
    var: int = typer.Argument(..., help="Macro variable number."),
    value: float = typer.Argument(..., help="New value."),
    host: str = HostOpt,
    port: str = PortOpt,
    baud: int = BaudOpt,
    timeout: float = TimeoutOpt,
    unsafe: bool = typer.Option(False, "--unsafe", help="Allow writing to the machine."),
    any_variable: bool = typer.Option(
        False, "--any-variable", help="Also allow variables outside the general-purpose globals."
    ),
) -> None:
    """Write a macro variable (?E). Refused without --unsafe."""
    from opendnc.haas.mdc_client import check_macro_write

    with cli_errors():
        # what the control would refuse is refused here, with the reason, before connecting
        check_macro_write(var, value, safe_mode=not unsafe, allow_any_variable=any_variable)
        with mdc_client(
            host, port, baud, timeout, safe_mode=not unsafe, allow_any_variable=any_variable
        ) as client:
            client.macro_set(var, value)
        console.print(f"#{var} set to {value:g}", highlight=False)


def _transfer_bar(label: str, json_out: bool, *extra: ProgressColumn) -> Progress:
    """The byte progress bar of a transfer; hidden when the result goes out as JSON."""
    from rich.progress import BarColumn, DownloadColumn, Progress, TextColumn, TransferSpeedColumn

    return Progress(
        TextColumn(label),
        BarColumn(),
        DownloadColumn(),
        TransferSpeedColumn(),
        *extra,
        console=console,
        transient=json_out,
        disable=json_out,
    )


@share_app.command("push")
def share_push(
    files: list[Path] = typer.Argument(..., help="Program files to copy."),
    to: str = typer.Option(..., "--to", help="smb://HOST[:PORT]/SHARE/PATH or a mounted folder."),
    user: str | None = typer.Option(None, "--user", "-u", help="SMB user name."),
    password: str | None = typer.Option(
        None, "--password", envvar="OPENDNC_SMB_PASSWORD", help="SMB password (or env)."
    ),
    json_out: bool = ResultJsonOpt,
) -> None:
    """Copy programs to a Haas Net Share; each file appears whole or not at all."""
    from opendnc.haas import share

    with cli_errors():
        target = share.parse_target(to)
        total = sum(f.stat().st_size for f in files if f.is_file())
        with _transfer_bar("push", json_out) as bar:
            task = bar.add_task("push", total=total)
            results = share.push(
                files,
                target,
                username=user,
                password=password,
                progress=lambda n: bar.advance(task, n),
            )
        if json_out:
            print_json(results)
        else:
            for result in results:
                console.print(f"{result.source} -> {result.destination} ({result.size} bytes)")


# --------------------------------------------------------------------------- drip-feed (DNC)
class SentBytes:
    """Progress of a drip-feed in bytes on the wire, not in bytes of the file.

    With ``--from-line`` the lines before the restart are only scanned and a modal header is
    sent instead, so the file size overstates the transfer. :meth:`plan` runs the same feed
    once without a port to learn the wire total; :meth:`at` turns the file offset the engine
    reports into bytes sent, in proportion over the part of the file that is sent.
    """

    def __init__(self, total: int, first_offset: int, file_size: int) -> None:
        self.total = total
        self.first_offset = first_offset
        self.file_size = file_size

    @classmethod
    def plan(cls, path: Path, config: DncConfig, from_line: int) -> SentBytes:
        """Scan ``path`` as the drip-feed will send it."""
        from opendnc.haas.dnc import ProgramFeed

        feed = ProgramFeed(path, eob=config.eob, from_line=from_line, retract=config.retract)
        total, first = 0, -1
        try:
            for block in feed:
                if first < 0:
                    first = feed.position
                total += len(block)
        finally:
            feed.close()
        return cls(total, max(first, 0), feed.total)

    def at(self, offset: int) -> int:
        """Bytes on the wire once the feed has read the file up to ``offset``."""
        span = self.file_size - self.first_offset
        if span <= 0 or offset >= self.file_size:
            return self.total
        done = max(0, offset - self.first_offset)
        return min(self.total, round(self.total * done / span))


@app.command("dnc")
def dnc_cmd(
    file: Path = typer.Argument(..., help="Program to drip-feed.", exists=True, dir_okay=False),
    port: str = typer.Option(
        ...,
        "--port",
        help="Serial device (/dev/ttyUSB0, COM3), tcp://HOST:PORT or socket:// (serial server), "
        "rfc2217://.",
    ),
    from_line: int = typer.Option(
        1, "--from-line", help="Restart at this file line (modal header re-sent first)."
    ),
    baud: int = typer.Option(9600, "--baud", help="Baud rate (Setting 11)."),
    parity: str = typer.Option("N", "--parity", help="N, E or O (Setting 12)."),
    eob: str = typer.Option("lf", "--eob", help="EOB (Setting 25): lf, cr, crlf, crcr, lflf."),
    flow: str = typer.Option("xonxoff", "--flow", help="xonxoff, rtscts or none (Setting 14)."),
    chunk: int = typer.Option(16, "--chunk", help="Bytes per write (bounds the XOFF overrun)."),
    xoff_timeout: float = typer.Option(
        120.0, "--xoff-timeout", help="Fail if XOFF lasts longer (seconds, 0 = never)."
    ),
    no_retract: bool = typer.Option(
        False, "--no-retract", help="Restart header without the G91 G28 Z0. retract."
    ),
    wait_for_xon: bool = typer.Option(
        False, "--wait-for-xon", help="Start only after the control's first DC1."
    ),
    unsafe: bool = typer.Option(
        False, "--unsafe", help="Required: the program runs on the machine."
    ),
    json_out: bool = ResultJsonOpt,
) -> None:
    """Drip-feed FILE to a control in DNC mode, with XON/XOFF handled by opendnc."""
    from rich.progress import TimeRemainingColumn

    from opendnc.haas.dnc import (
        DncConfig,
        DncEvent,
        Flow,
        Paused,
        open_dnc_port,
        stream_program,
    )
    from opendnc.transport.base import PortStream
    from opendnc.xmodem.haas import Eob

    with cli_errors():
        try:
            config = DncConfig(
                flow=Flow(flow.lower()),
                chunk=chunk,
                xoff_timeout=xoff_timeout,
                eob=Eob(eob.lower()),
                retract=not no_retract,
                wait_for_xon=wait_for_xon,
            )
        except ValueError as exc:
            raise InputError(f"bad option: {exc}") from None
        sent = SentBytes.plan(file, config, from_line)
        # the port opens before the bar (one error line if it does not), but only for a run
        # that may start: a locked one is refused before any port is touched
        link: str | PortStream = port
        if unsafe:
            link = open_dnc_port(port, baud, parity=parity, flow=config.flow)
        with (
            contextlib.closing(link) if not isinstance(link, str) else contextlib.nullcontext(),
            _transfer_bar("dnc {task.fields[state]}", json_out, TimeRemainingColumn()) as bar,
        ):
            task = bar.add_task("dnc", total=sent.total, state="[green]run[/]")

            def on_event(event: DncEvent) -> None:
                paused = isinstance(event, Paused)
                bar.update(task, state="[yellow]XOFF[/]" if paused else "[green]run[/]")

            report = stream_program(
                link,
                file,
                from_line=from_line,
                config=config,
                safe_mode=not unsafe,
                progress=lambda done, _total: bar.update(task, completed=sent.at(done)),
                on_event=on_event,
            )
        if json_out:
            print_json(report)
            return
        if report.restart is not None:
            for warning in report.restart.warnings:
                console.print(f"[yellow]warning:[/] {warning}", highlight=False)
            console.print(
                f"restart at line {report.restart.line}, header re-sent: "
                + " | ".join(report.restart.preamble),
                highlight=False,
            )
        console.print(
            f"{report.bytes_sent} bytes, {report.lines} blocks in {report.seconds:.1f} s; "
            f"XOFF {report.xoffs}x ({report.paused_seconds:.1f} s held)",
            highlight=False,
        )


# --------------------------------------------------------------------------- end-to-end checks
def punch_back_check(
    stream: ByteStream,
    file: Path,
    sent: bytes,
    *,
    eob: str,
    timeout: float,
    ignore_spaces: bool,
) -> VerifyResult:
    """Wait for the control's punch of ``file`` on ``stream`` and compare (shared with
    ``xmodem send --verify``); one stderr line tells the operator what to do."""
    from opendnc.haas.verify import verify_by_punch
    from opendnc.xmodem.haas import Eob, program_header

    try:
        eob_choice = Eob(eob.lower())
    except ValueError:
        raise InputError(f"bad --eob {eob!r}: use lf, cr, crlf, crcr or lflf") from None
    header = program_header(sent)
    name = header.name if header is not None else file.name
    err_console.print(
        f"waiting up to {timeout:g} s for the control to punch {name} "
        "(at the control: select it and send it, Setting 14 = XMODEM)",
        highlight=False,
        soft_wrap=True,
    )
    return verify_by_punch(
        stream, sent, eob=eob_choice, timeout=timeout, ignore_spaces=ignore_spaces
    )


def verified_line(result: VerifyResult, file: Path) -> str:
    """The one line a successful check prints."""
    name = result.program or "the program"
    return f"verified: {name} on the control matches {file.name} ({result.lines} lines)"


@app.command("verify")
def verify_cmd(
    file: Path = typer.Argument(..., help="The program as sent.", exists=True, dir_okay=False),
    port: str = typer.Option(
        ..., "--port", help="Serial device, tcp://HOST:PORT, socket:// or rfc2217:// URL."
    ),
    baud: int = typer.Option(9600, "--baud", help="Baud rate (Setting 11)."),
    eob: str = typer.Option("lf", "--eob", help="EOB (Setting 25): lf, cr, crlf, crcr, lflf."),
    timeout: float = typer.Option(
        300.0, "--timeout", help="Seconds to wait for the operator to start the punch."
    ),
    ignore_spaces: bool = typer.Option(
        False, "--ignore-spaces", help="Ignore blanks (Setting 41 adds spaces when punching)."
    ),
    json_out: bool = ResultJsonOpt,
) -> None:
    """Check a load end to end: receive the control's punch of FILE and compare them.

    Checksum XModem can let two cancelling bit errors through; this finds them. Line ends,
    leader, SUB padding and the % lines do not count.
    """
    from opendnc.xmodem.files import open_port

    with cli_errors():
        try:
            sent = file.read_bytes()
        except OSError as exc:
            raise InputError(f"cannot read {file}: {exc.strerror or exc}") from None
        with contextlib.closing(open_port(port, baud, "N")) as stream:
            result = punch_back_check(
                stream, file, sent, eob=eob, timeout=timeout, ignore_spaces=ignore_spaces
            )
        if json_out:
            print_json(result)
        else:
            console.print(verified_line(result, file), highlight=False, soft_wrap=True)


@app.command("check-line")
def check_line_cmd(
    files: list[Path] = typer.Argument(..., help="Program files.", exists=True, dir_okay=False),
    add: bool = typer.Option(
        False, "--add", help="Write (or renew) the (ODNC CRC32 ...) line after the O line."
    ),
    json_out: bool = ResultJsonOpt,
) -> None:
    """Check, or add, a program's (ODNC CRC32 ...) line: a sum that travels in the program.

    A program that carries it can be checked whenever it is punched, by whoever receives it
    (`xmodem recv` refuses one that does not match). Exit status 1 if any file fails.
    """
    from opendnc.atomicfile import atomic_write
    from opendnc.haas.verify import CheckState, add_check_line, check_line

    with cli_errors():
        results = []
        for file in files:
            data = file.read_bytes()
            if add:
                data = add_check_line(data)
                with atomic_write(file) as out:
                    out.write(data)
            result = check_line(data)
            results.append({"file": str(file), **dataclasses.asdict(result)})
            if not json_out:
                state = {
                    CheckState.OK: f"ok ({result.actual})",
                    CheckState.MISSING: "no check line (add one with --add)",
                    CheckState.MISMATCH: (
                        f"DAMAGED: the line says {result.expected}, the text sums to "
                        f"{result.actual}"
                    ),
                }[result.state]
                console.print(f"{file}: {state}", highlight=False, soft_wrap=True)
        if json_out:
            print_json(results)
        if any(r["state"] == CheckState.MISMATCH for r in results):
            raise typer.Exit(1)
