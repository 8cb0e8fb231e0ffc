"""`opendnc lsv2` machine-data commands: status, PLC, data paths, parameters, errors, screen,
tables, scope and the operations log. Registered on the group by :mod:`opendnc.cli.lsv2`."""

from __future__ import annotations

import csv
import io
import sys
from collections.abc import Callable
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from opendnc.cli.common import cli_errors, console, print_json, to_jsonable
from opendnc.cli.lsv2_session import JsonOpt, connect, relabel, require_unsafe, want_json
from opendnc.errors import ControlRefused, InputError

if TYPE_CHECKING:  # the LSV2 stack is imported by the commands that talk to a control
    from opendnc.lsv2 import Client
    from opendnc.lsv2.payloads import ScopeChannel, ScopeSignal
    from opendnc.lsv2.runinfo import NcError, Overrides

__all__ = ["COMMANDS", "GROUPS"]

plc_app = typer.Typer(help="PLC memory.", no_args_is_help=True)
data_app = typer.Typer(help="Data paths (iTNC 530).", no_args_is_help=True)
param_app = typer.Typer(help="Machine parameters.", no_args_is_help=True)
table_app = typer.Typer(help="Table files (tool, pocket, datum ...).", no_args_is_help=True)
scope_app = typer.Typer(help="Remote scope (iTNC 530).", no_args_is_help=True)


def _optional(read: Callable[[], Any]) -> Any:
    """A value the family may not support: ``None`` (shown as n/a) instead of an error."""
    try:
        return read()
    except ControlRefused:
        return None


def status(ctx: typer.Context, json_out: bool = JsonOpt) -> None:
    """Execution mode, program state, selected program, overrides, axes and tool."""
    with cli_errors(), connect(ctx) as tnc:
        data = machine_status(tnc)
        if want_json(ctx, json_out):
            print_json(data)
            return
        from rich.table import Table

        table = Table(show_header=False, title=f"{tnc.versions.model} status")
        for key, value in data.items():
            table.add_row(key.replace("_", " "), _text(value))
        console.print(table)


def machine_status(tnc: Client) -> dict[str, Any]:
    """What the control tells about its state; unsupported selectors are ``None``."""
    axes = _optional(tnc.axes_position)
    overrides = _optional(tnc.overrides)
    program = _optional(tnc.selected_program)
    tool = _optional(tnc.current_tool)
    mode = _optional(tnc.execution_mode)
    state = _optional(tnc.program_state)
    return {
        "execution_mode": mode.name.lower() if mode is not None else None,
        "program_state": state.name.lower() if state is not None else None,
        "selected_program": program.main or None if program is not None else None,
        "current_program": program.current or None if program is not None else None,
        "program_line": program.line if program is not None else None,
        "overrides": _percent(overrides) if overrides is not None else None,
        "axes": {a.name: a.text for a in axes.axes} if axes is not None else None,
        "tool": to_jsonable(tool) if tool is not None else None,
    }


def _percent(overrides: Overrides) -> dict[str, float]:
    # the wire counts in 0.01 % (docs/lsv2.md, R_RI 25); people read percent
    feed, spindle, rapid = overrides.percent
    return {"feed_percent": feed, "spindle_percent": spindle, "rapid_percent": rapid}


def _text(value: Any) -> str:
    if value is None:
        return "n/a"
    if isinstance(value, float):
        return f"{value:g}"
    if isinstance(value, dict):
        if all(str(k).endswith("_percent") for k in value):
            return "  ".join(f"{str(k)[: -len('_percent')]} {_text(v)} %" for k, v in value.items())
        return "  ".join(f"{k}={_text(v)}" for k, v in value.items() if v is not None)
    return str(value)


@plc_app.command("read")
def plc_read(
    ctx: typer.Context,
    operand: str = typer.Argument(..., help="Operand, e.g. M100, W4, D8, B0, S0, I5."),
    count: int = typer.Argument(1, help="Number of consecutive operands."),
    json_out: bool = JsonOpt,
) -> None:
    """Read PLC operands."""
    with cli_errors():
        from opendnc.lsv2 import parse_operand
        from opendnc.lsv2.plc import PlcOperand

        start = parse_operand(operand)
        if count < 1:
            raise InputError("COUNT must be at least 1")
        with connect(ctx) as tnc, relabel(f"plc read {operand}"):
            values = tnc.read_plc(start, count)
        names = [PlcOperand(start.memory, start.index + i).notation for i in range(len(values))]
        if want_json(ctx, json_out):
            print_json([{"operand": n, "value": v} for n, v in zip(names, values, strict=True)])
        else:
            for name, value in zip(names, values, strict=True):
                console.print(f"{name:8} {value}", highlight=False)


@data_app.command("read")
def data_read(
    ctx: typer.Context,
    path: str = typer.Argument(..., help="Data path, e.g. /TABLE/TOOL/T/1/L."),
    json_out: bool = JsonOpt,
) -> None:
    """Read a value by data path (iTNC 530)."""
    with cli_errors(), connect(ctx) as tnc, relabel(f"data read {path}"):
        value = tnc.read_data_path(path)
        if want_json(ctx, json_out):
            print_json({"path": path, "value": value})
        else:
            console.print(str(value), highlight=False)


@param_app.command("get")
def param_get(ctx: typer.Context, name: str, json_out: bool = JsonOpt) -> None:
    """Read a machine parameter."""
    with cli_errors(), connect(ctx) as tnc, relabel(f"param get {name}"):
        value = tnc.read_machine_parameter(name)
        if want_json(ctx, json_out):
            print_json({"name": name, "value": value})
        else:
            console.print(value, highlight=False, markup=False)


@param_app.command("set")
def param_set(
    ctx: typer.Context,
    name: str,
    value: str,
    temporary: bool = typer.Option(False, "--temporary", help="Only until the next restart."),
) -> None:
    """Write a machine parameter (needs --unsafe)."""
    with cli_errors():
        require_unsafe(ctx, f"param set {name}")
        with connect(ctx) as tnc, relabel(f"param set {name}"):
            tnc.write_machine_parameter(name, value, temporary=temporary)
        console.print(f"{name} = {value}", highlight=False, markup=False)


def errors(ctx: typer.Context, json_out: bool = JsonOpt) -> None:
    """Pending NC error messages (iTNC 530; others report n/a)."""
    with cli_errors(), connect(ctx) as tnc:
        found = _optional(tnc.nc_errors)
        if want_json(ctx, json_out):
            listed = [_nc_error(e) for e in found or []]
            print_json({"supported": found is not None, "errors": listed})
        elif found is None:
            console.print(f"n/a: {tnc.versions.model} does not report NC errors over LSV2")
        elif not found:
            console.print("no NC errors")
        else:
            for err in found:
                described = _nc_error(err)
                console.print(
                    f"{described['class']} (group {err.group}, number {described['number_hex']}): "
                    f"{err.text}",
                    highlight=False,
                )


def _nc_error(err: NcError) -> dict[str, object]:
    """An NC error with its class as a word and its number also as unsigned hex."""
    from opendnc.lsv2.errorclass import class_name

    return {
        "class": class_name(err.error_class),
        "class_number": err.error_class,
        "group": err.group,
        "number": err.number,
        "number_hex": f"0x{err.number & 0xFFFFFFFF:08X}",
        "text": err.text,
    }


def screenshot(
    ctx: typer.Context, out: Path = typer.Argument(..., help="OUT.bmp or OUT.png")
) -> None:
    """Save a screenshot of the control (BMP or PNG by extension)."""
    with cli_errors():
        if out.suffix.lower() not in (".bmp", ".png"):
            raise InputError(f"{out}: use a .bmp or .png file name")
        with connect(ctx) as tnc, relabel("screenshot"):
            bmp = tnc.screen_dump(out)
        console.print(f"saved {out} ({out.stat().st_size:,} bytes, BMP was {len(bmp):,})")


@table_app.command("get")
def table_get(
    ctx: typer.Context,
    remote: str = typer.Argument(..., help="Remote table, e.g. TNC:/table/tool.t"),
    out: str = typer.Argument(..., help="OUT.csv or OUT.json (- = JSON on stdout)."),
) -> None:
    """Download a table file and save it as CSV or JSON."""
    with cli_errors():
        suffix = Path(out).suffix.lower()
        if out != "-" and suffix not in (".csv", ".json"):
            raise InputError(f"{out}: use a .csv or .json file name (or - for stdout)")
        with connect(ctx) as tnc, relabel(f"table get {remote}"):
            table = tnc.read_table(remote)
        text = table.to_csv() if suffix == ".csv" else table.to_json()
        if out == "-":
            sys.stdout.write(text if text.endswith("\n") else text + "\n")
            return
        try:
            Path(out).write_text(text, encoding="utf-8")
        except OSError as exc:
            raise InputError(f"cannot write {out}: {exc.strerror or exc}") from exc
        console.print(f"{remote}: {len(table.rows)} rows -> {out}", highlight=False)


@scope_app.command("channels")
def scope_channels(ctx: typer.Context, json_out: bool = JsonOpt) -> None:
    """List the remote-scope channels (iTNC 530)."""
    with cli_errors(), connect(ctx) as tnc, relabel("scope channels"):
        channels = tnc.scope_channels()
        if want_json(ctx, json_out):
            # the wire pads the signal list with "-" and ""; a signal's index is its position,
            # so only the padding at the end goes
            print_json([{**to_jsonable(ch), "signals": _named(ch.signals)} for ch in channels])
            return
        from rich.table import Table

        table = Table("no", "name", "type", "interval µs", "signals")
        for ch in channels:
            signals = " ".join(s for s in ch.signals if s != "-")
            table.add_row(str(ch.number), ch.name, str(ch.channel_type), str(ch.interval), signals)
        console.print(table)


def _named(signals: list[str] | tuple[str, ...]) -> list[str]:
    names = list(signals)
    while names and names[-1] in ("", "-"):
        names.pop()
    return names


def _signal(text: str, channels: dict[int, ScopeChannel] | None = None) -> ScopeSignal:
    """Parse CHANNEL[:SIGNAL[:ADDRESS]]; SIGNAL is an index or a name `scope channels` lists."""
    parts = text.split(":")
    if not 1 <= len(parts) <= 3:
        raise InputError(f"bad signal {text!r}: use CHANNEL[:SIGNAL[:ADDRESS]]")
    try:
        numbers = [int(parts[0], 0)]
        if len(parts) > 1:
            numbers.append(_selector(parts[1], (channels or {}).get(numbers[0])))
        numbers.extend(int(p, 0) for p in parts[2:])
    except ValueError:
        raise InputError(f"bad signal {text!r}: use CHANNEL[:SIGNAL[:ADDRESS]]") from None
    from opendnc.lsv2.payloads import ScopeSignal

    return ScopeSignal(*numbers)


def _signal_syntax(text: str) -> None:
    # checked before connecting, so a typo fails fast; names are resolved once connected
    parts = text.split(":")
    if not 1 <= len(parts) <= 3 or not all(p.strip() for p in parts):
        raise InputError(f"bad signal {text!r}: use CHANNEL[:SIGNAL[:ADDRESS]]")
    try:
        for number in (parts[0], *parts[2:]):
            int(number, 0)
    except ValueError:
        raise InputError(f"bad signal {text!r}: use CHANNEL[:SIGNAL[:ADDRESS]]") from None


def _selector(text: str, channel: ScopeChannel | None) -> int:
    try:
        return int(text, 0)
    except ValueError:
        if channel is None:
            raise
    names = [name.upper() for name in channel.signals]
    if text.upper() not in names:
        raise InputError(
            f"channel {channel.number} ({channel.name}) has no signal {text!r}: "
            f"use one of {' '.join(_named(channel.signals))}"
        )
    return names.index(text.upper())


def _signal_name(signal: ScopeSignal, channel: ScopeChannel | None) -> str:
    if channel is None:
        return f"ch{signal.channel}.{signal.selector}"
    if signal.selector < len(channel.signals):
        return f"{channel.name} {channel.signals[signal.selector]}"
    return f"{channel.name} {signal.selector}"


@scope_app.command("record")
def scope_record(
    ctx: typer.Context,
    out: Path = typer.Argument(..., help="CSV file for the samples."),
    signal: list[str] = typer.Option(
        ...,
        "--signal",
        "-s",
        help="CHANNEL[:SIGNAL[:ADDRESS]], repeatable; SIGNAL by index or name (0:X).",
    ),
    interval: int = typer.Option(21000, "--interval", help="Sampling interval in µs."),
    blocks: int = typer.Option(1, "--blocks", help="Blocks of 32 samples."),
) -> None:
    """Record scope signals into a CSV file (iTNC 530)."""
    with cli_errors():
        for s in signal:
            _signal_syntax(s)
        with connect(ctx) as tnc, relabel("scope record"):
            channels = {ch.number: ch for ch in tnc.scope_channels()}
            signals = [_signal(s, channels) for s in signal]
            rec = tnc.scope_record(signals, interval=interval, blocks=blocks)
        buf = io.StringIO()
        writer = csv.writer(buf)
        names = [
            f"{_signal_name(s, channels.get(s.channel))} [{i.unit}]"
            for s, i in zip(rec.signals, rec.info, strict=False)
        ]
        writer.writerow(["time_us", *names])
        for row, values in enumerate(zip(*rec.values, strict=False)):
            writer.writerow([row * rec.interval, *values])
        try:
            out.write_text(buf.getvalue(), encoding="utf-8")
        except OSError as exc:
            raise InputError(f"cannot write {out}: {exc.strerror or exc}") from exc
        console.print(f"{len(rec.values[0]) if rec.values else 0} samples -> {out}")


def log(
    ctx: typer.Context,
    out: Path = typer.Argument(..., help="Local file for the operations log."),
    days: int = typer.Option(7, "--days", help="Entries of the last N days."),
) -> None:
    """Have the control write its operations log and download it."""
    with cli_errors(), connect(ctx) as tnc, relabel("log"):
        # The control writes the log into its current folder; the download looks in TNC:\.
        tnc.change_dir("TNC:\\")
        since = datetime.now(UTC) - timedelta(days=days)
        data = tnc.operations_log(out, since=since)
        console.print(f"operations log: {len(data):,} bytes -> {out}", highlight=False)


COMMANDS: dict[str, Callable[..., None]] = {
    "status": status,
    "errors": errors,
    "screenshot": screenshot,
    "log": log,
}
GROUPS: dict[str, typer.Typer] = {
    "plc": plc_app,
    "data": data_app,
    "param": param_app,
    "table": table_app,
    "scope": scope_app,
}
