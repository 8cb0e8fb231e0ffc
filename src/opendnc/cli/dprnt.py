"""`opendnc dprnt` commands: capture DPRNT output."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import typer
from rich.text import Text

from opendnc.cli.common import cli_errors, console, err_console
from opendnc.haas.listen import (
    CallbackSink,
    CapturedLine,
    CsvSink,
    DprntListener,
    JsonlSink,
    LineSink,
    open_source,
)

app = typer.Typer(help="Capture DPRNT output from a Haas.", no_args_is_help=True)


@app.command("listen")
def listen(
    port: str = typer.Option(
        ...,
        "--port",
        help="Serial device (/dev/ttyUSB0, COM3), tcp://HOST:PORT (NGC Setting 263), "
        "socket:// or rfc2217://.",
    ),
    csv_path: Path | None = typer.Option(None, "--csv", help="Append lines to this CSV file."),
    jsonl_path: Path | None = typer.Option(None, "--jsonl", help="Append lines as JSON Lines."),
    baud: int = typer.Option(9600, "--baud", help="Serial baud rate (Setting 11)."),
    max_lines: int | None = typer.Option(None, "--max-lines", help="Stop after N lines."),
    max_connects: int | None = typer.Option(
        None, "--max-connects", help="Stop after N connections ended (default: reconnect forever)."
    ),
    json_out: bool = typer.Option(False, "--json", help="Print each line as JSON on stdout."),
    retry: bool = typer.Option(
        False,
        "--retry",
        help="Keep trying while the port does not open (default: fail at once with the reason).",
    ),
) -> None:
    """Timestamp, parse and store every DPRNT line; reconnect with backoff on disconnect.

    A line over 4096 bytes is dropped whole and reported; a line cut by a disconnect is kept
    and marked (CSV column ``complete`` = ``no``, JSON ``"complete": false``).
    """
    with cli_errors():
        sinks: list[LineSink] = []
        if csv_path is not None:
            sinks.append(CsvSink(csv_path))
        if jsonl_path is not None:
            sinks.append(JsonlSink(jsonl_path))
        if json_out:
            sinks.append(JsonlSink(stream=sys.stdout))
        else:
            sinks.append(CallbackSink(_show))

        listener = DprntListener(
            port,
            sinks,
            opener=lambda spec: open_source(spec, baudrate=baud),
            on_status=lambda message: err_console.print(f"[dim]{message}[/]", highlight=False),
            retry_unopened=retry,
        )
        try:
            stats = listener.run(max_lines=max_lines, max_connects=max_connects)
        finally:
            for sink in sinks:
                sink.close()
        summary = {"lines": stats.lines, "cut": stats.cut, "dropped": stats.dropped}
        err_console.print(f"[dim]{json.dumps(summary)}[/]", highlight=False)


def _show(line: CapturedLine) -> None:
    # rich.Text keeps captured brackets from being read as markup
    text = Text(line.timestamp.strftime("%H:%M:%S.%f")[:-3] + " ", style="dim")
    text.append(line.text)
    if not line.complete:
        text.append("  [cut: the link ended before the line end]", style="yellow")
    if line.numbers:
        text.append("  " + " ".join(f"{n:g}" for n in line.numbers), style="cyan")
    console.print(text, highlight=False)
