"""`opendnc dprnt` commands: capture DPRNT output."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import typer
from rich.text import Text

from opendnc.cli.common import cli_errors, console, err_console, ready_file
from opendnc.haas.listen import (
    CallbackSink,
    CapturedLine,
    CsvSink,
    DprntListener,
    JsonlSink,
    LineSink,
    open_source,
)
from opendnc.transport.base import ByteStream

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
    ready: Path | None = typer.Option(
        None,
        "--ready-file",
        help="Create this file once the port is open, remove it at the end (a script waits "
        "for it with `opendnc wait FILE` before it starts the program that prints).",
    ),
) -> None:
    """Timestamp, parse and store every DPRNT line; reconnect with backoff on disconnect.

    A line over 4096 bytes is dropped whole and reported; a line cut by a disconnect is kept
    and marked (CSV column ``complete`` = ``no``, JSON ``"complete": false``).
    """
    with cli_errors(), ready_file(ready) as mark_ready:
        sinks: list[LineSink] = []
        if csv_path is not None:
            sinks.append(CsvSink(csv_path))
        if jsonl_path is not None:
            sinks.append(JsonlSink(jsonl_path))
        if json_out:
            sinks.append(JsonlSink(stream=sys.stdout))
        else:
            sinks.append(CallbackSink(_show))

        def opener(spec: str) -> ByteStream:
            stream = open_source(spec, baudrate=baud)
            mark_ready()  # lines printed from now on are read
            return stream

        listener = DprntListener(
            port,
            sinks,
            opener=opener,
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
    if line.fields:
        # each number with the label written before it in the line: X=0 Z=-0.5
        shown = (f"{f.label}={f.value:g}" if f.label else f"{f.value:g}" for f in line.fields)
        text.append("  " + " ".join(shown), style="cyan")
    console.print(text, highlight=False)
