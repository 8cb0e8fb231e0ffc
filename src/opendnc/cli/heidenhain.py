"""`opendnc heidenhain`: Heidenhain's blockwise serial file protocol (FE modes, not LSV2)."""

from __future__ import annotations

from pathlib import Path

import typer

from opendnc.atomicfile import atomic_write
from opendnc.cli.common import cli_errors, console
from opendnc.errors import InputError
from opendnc.heidenhain.blockwise import BlockwiseSettings
from opendnc.heidenhain.blockwise_io import BlockLine, open_block_line, receive_file, send_file

app = typer.Typer(
    help="Heidenhain blockwise serial file transfer (FE1/FE2/EXT modes; LSV2 is `opendnc lsv2`).",
    no_args_is_help=True,
)

PortOpt = typer.Option(..., "--port", help="Serial device, socket://HOST:PORT or rfc2217://.")
BaudOpt = typer.Option(9600, "--baud", help="Line rate.")
ParityOpt = typer.Option("E", "--parity", help="Parity N, E or O (older units: 7E1).")
BytesizeOpt = typer.Option(7, "--bytesize", help="Data bits, 7 or 8.")
StopbitsOpt = typer.Option(1.0, "--stopbits", help="Stop bits.")
EotOpt = typer.Option(
    "receiver", "--eot-by", help="Who sends the final EOT after ETX: receiver or sender."
)
TimeoutOpt = typer.Option(30.0, "--timeout", help="Seconds to wait for the other side.")


def _settings(eot_by: str, timeout: float) -> BlockwiseSettings:
    if eot_by not in ("receiver", "sender"):
        raise InputError(f"--eot-by must be receiver or sender, got {eot_by!r}")
    return BlockwiseSettings(idle_timeout=timeout, eot_by=eot_by)  # type: ignore[arg-type]


@app.command("send")
def send(
    file: Path = typer.Argument(..., help="NC program to send."),
    port: str = PortOpt,
    baud: int = BaudOpt,
    parity: str = ParityOpt,
    bytesize: int = BytesizeOpt,
    stopbits: float = StopbitsOpt,
    name: str | None = typer.Option(None, "--name", help="Name on the control (default: FILE's)."),
    wait_request: bool = typer.Option(
        False, "--wait-request", help="Wait for the control to ask for the file (K header)."
    ),
    eot_by: str = EotOpt,
    timeout: float = TimeoutOpt,
) -> None:
    """Send one program line by line (H header, or answering the control's request)."""
    with cli_errors():
        try:
            data = file.read_bytes()
        except OSError as exc:
            raise InputError(f"cannot read {file}: {exc.strerror or exc}") from exc
        line = BlockLine(port, baud, parity.upper(), bytesize, stopbits)
        stream = open_block_line(line)
        try:
            done = send_file(
                stream,
                name or file.name,
                data,
                wait_request=wait_request,
                settings=_settings(eot_by, timeout),
            )
        finally:
            stream.close()
        console.print(
            f"sent {done.name}: {done.lines} lines ({done.resent} blocks repeated)",
            highlight=False,
        )


@app.command("recv")
def recv(
    folder: Path = typer.Argument(Path("."), help="Folder to store the received program in."),
    port: str = PortOpt,
    baud: int = BaudOpt,
    parity: str = ParityOpt,
    bytesize: int = BytesizeOpt,
    stopbits: float = StopbitsOpt,
    request: str | None = typer.Option(
        None, "--request", help="Ask the control for this file (K header) instead of waiting."
    ),
    eot_by: str = EotOpt,
    timeout: float = TimeoutOpt,
) -> None:
    """Receive one program (stored only when complete)."""
    with cli_errors():
        if not folder.is_dir():
            raise InputError(f"{folder} is not a folder")
        line = BlockLine(port, baud, parity.upper(), bytesize, stopbits)
        stream = open_block_line(line)
        try:
            name, data = receive_file(stream, request, settings=_settings(eot_by, timeout))
        finally:
            stream.close()
        target = folder / name
        try:
            with atomic_write(target) as out:
                out.write(data)
        except OSError as exc:
            raise InputError(f"cannot write {target}: {exc.strerror or exc}") from exc
        count = data.count(b"\n")
        console.print(f"received {name}: {count} lines -> {target}", highlight=False)
