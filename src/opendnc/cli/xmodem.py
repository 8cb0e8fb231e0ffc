"""`opendnc xmodem send|recv`: move programs to and from a control over XModem."""

from __future__ import annotations

import contextlib
from pathlib import Path
from typing import TYPE_CHECKING

import typer

from opendnc.cli.common import cli_errors, console, err_console, print_json
from opendnc.xmodem.framing import Mode
from opendnc.xmodem.haas import Eob

if TYPE_CHECKING:  # the transfer machinery loads with the command that runs, not for --help
    from rich.progress import Progress

    from opendnc.xmodem.events import Event
    from opendnc.xmodem.files import SendReport

app = typer.Typer(help="XModem transfers (Haas RS-232: checksum mode, setting 14 = XMODEM)")

PORT_HELP = "Serial device (/dev/ttyUSB0, COM3), tcp://HOST:PORT, socket://HOST:PORT, rfc2217://..."


def _progress() -> Progress:
    from rich.progress import (
        BarColumn,
        DownloadColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TransferSpeedColumn,
    )

    columns = [
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        DownloadColumn(),
        TransferSpeedColumn(),
        TimeElapsedColumn(),
    ]
    return Progress(*columns, console=err_console, transient=False)


def _report_event(event: Event) -> None:
    from opendnc.xmodem.events import FallbackToSmall, Retry

    if isinstance(event, Retry):
        err_console.print(f"[yellow]retry[/] block {event.seq} #{event.attempt}: {event.reason}")
    elif isinstance(event, FallbackToSmall):
        err_console.print(f"[yellow]falling back to 128-byte blocks at block {event.seq}[/]")


@app.command("send")
def send_cmd(
    file: Path = typer.Argument(..., help="Program file to send", exists=True, dir_okay=False),
    port: str = typer.Option(..., "--port", "-p", help=PORT_HELP),
    mode: Mode = typer.Option(
        Mode.CHECKSUM, "--mode", help="checksum (Haas), crc or 1k (falls back as needed)"
    ),
    baud: int = typer.Option(9600, "--baud", help="Baud rate (Haas setting 11)"),
    parity: str = typer.Option("N", "--parity", help="N, E or O (XModem on a Haas needs N)"),
    eob: Eob | None = typer.Option(
        None, "--eob", help="Convert line ends to the control's setting 25 (default: as is)"
    ),
    timeout: float = typer.Option(60.0, "--timeout", help="Seconds to wait for the receiver"),
    turnaround: float = typer.Option(
        0.0, "--turnaround", help="Milliseconds to pause after each ACK (lrzsz rx on a pty)"
    ),
    binary: bool = typer.Option(
        False, "--binary", help="Send any bytes (default: refuse a file that is not NC text)"
    ),
    verify: bool = typer.Option(
        False,
        "--verify",
        help="Then wait for the control to punch the program back and compare (checksum "
        "mode cannot see two cancelling bit errors)",
    ),
    verify_timeout: float = typer.Option(
        300.0, "--verify-timeout", help="Seconds to wait for the punch back (--verify)"
    ),
    json_out: bool = typer.Option(False, "--json", help="Print the result as JSON"),
) -> None:
    """Send FILE to a receiver that is waiting (on a Haas: start the receive first).

    With --verify the operator then punches the program back (on a Haas: select it, SEND)
    and opendnc compares it with FILE, line by line.
    """
    from opendnc.nctext import check_program_file
    from opendnc.xmodem.files import open_port, send_file
    from opendnc.xmodem.sender import SenderConfig

    config = SenderConfig(start_timeout=timeout, turnaround=turnaround / 1000.0)
    with cli_errors():
        size = file.stat().st_size
        if not binary:  # a file that is no NC program is refused before the port opens
            check_program_file(file, action="not sent (--binary sends any bytes)")
        # the port opens before the bar: a port that does not open is one error line
        stream = open_port(port, baud, parity.upper())
        with contextlib.closing(stream):
            with _progress() as bar:
                task = bar.add_task(f"send {file.name}", total=size)
                report = send_file(
                    stream,
                    file,
                    mode=mode,
                    eob=eob,
                    config=config,
                    progress=lambda done, total: bar.update(task, completed=done, total=total),
                    on_event=_report_event,
                    binary=binary,
                )
            if not json_out:
                _print_sent(report)
            if not verify:
                if json_out:
                    print_json(report)
                return
            from opendnc.cli.haas import punch_back_check, verified_line

            verified = punch_back_check(
                stream,
                file,
                file.read_bytes(),
                eob=(eob or Eob.LF).value,
                timeout=verify_timeout,
                ignore_spaces=False,
            )
        if json_out:
            print_json({"sent": report, "verify": verified})
        else:
            console.print(verified_line(verified, file), highlight=False, soft_wrap=True)


def _print_sent(report: SendReport) -> None:
    from opendnc.xmodem.events import EotAnswer

    name = f" {report.program.name}" if report.program else ""
    console.print(
        f"sent{name} {report.size} bytes in {report.blocks} blocks, {report.seconds:.1f} s"
    )
    if report.eot_answer is EotAnswer.CAN:
        console.print("receiver answered EOT with CAN (Haas style); all blocks were ACKed")
    elif report.eot_answer in (EotAnswer.NONE, EotAnswer.CLOSED):
        console.print(
            "[yellow]receiver did not acknowledge EOT[/]; all data blocks were acknowledged"
        )


@app.command("recv")
def recv_cmd(
    out: str = typer.Argument(
        ..., help="Output file, or an existing folder (out/) to name it by O-number"
    ),
    port: str = typer.Option(..., "--port", "-p", help=PORT_HELP),
    mode: Mode = typer.Option(Mode.CHECKSUM, "--mode", help="checksum (Haas), crc or 1k"),
    baud: int = typer.Option(9600, "--baud", help="Baud rate (Haas setting 11)"),
    parity: str = typer.Option("N", "--parity", help="N, E or O"),
    timeout: float = typer.Option(
        60.0,
        "--timeout",
        help="Seconds to wait for the sender: to start, and for each block, retries included",
    ),
    eob: Eob | None = typer.Option(
        None, "--eob", help="Convert the control's setting-25 line ends to LF"
    ),
    keep_padding: bool = typer.Option(False, "--keep-padding", help="Keep trailing SUB bytes"),
    haas_eob_checksum: bool = typer.Option(
        False,
        "--haas-eob-checksum",
        help="Accept checksums computed with CR LF folded to LF (reported Haas quirk)",
    ),
    binary: bool = typer.Option(
        False,
        "--binary",
        help="Keep any bytes (default: NAK blocks that are not NC text, refuse such a file)",
    ),
    json_out: bool = typer.Option(False, "--json", help="Print the result as JSON"),
) -> None:
    """Receive one file into OUT (written to a temp file, renamed only on success)."""
    from opendnc.xmodem.files import check_output, open_port, receive_file
    from opendnc.xmodem.receiver import ReceiverConfig

    config = ReceiverConfig(
        start_timeout=timeout,
        idle_timeout=timeout,
        strip_padding=not keep_padding,
        fold_eob_checksum=haas_eob_checksum,
    )
    with cli_errors():
        check_output(out)  # a folder that does not exist is reported before the port opens
    # the port opens before the bar: a port that does not open is one error line
    with (
        cli_errors(),
        contextlib.closing(open_port(port, baud, parity.upper())) as stream,
        _progress() as bar,
    ):
        task = bar.add_task("receive", total=None)
        # one line at once: the user (and a script) sees the receiver is up and waiting
        err_console.print(f"waiting for a sender on {port} ({mode.value})", highlight=False)
        report = receive_file(
            stream,
            out,
            mode=mode,
            eob=eob,
            config=config,
            progress=lambda done, _total: bar.update(task, completed=done),
            on_event=_report_event,
            binary=binary,
        )
        bar.update(task, total=report.size, completed=report.size)
    if json_out:
        print_json(report)
        return
    name = f" program {report.program.name}" if report.program else ""
    check = {"ok": ", check line ok", "missing": ""}.get(report.check_line or "missing", "")
    console.print(
        f"received{name} {report.size} bytes in {report.blocks} blocks -> {report.path} "
        f"({report.seconds:.1f} s{check})"
    )
