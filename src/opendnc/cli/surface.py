"""`opendnc surface program|capture|report|measure`: map a surface with the machine's probe.

The maths and pictures need the ``surface`` extra (numpy, matplotlib, plotly); they are
imported only by ``report`` and ``measure``, so the rest of the command line stays light.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import typer
from rich.markup import escape

from opendnc.cli.common import cli_errors, console, err_console, print_json
from opendnc.errors import InputError
from opendnc.surface.capture import (
    CaptureReport,
    MatchEvent,
    Mismatch,
    Missing,
    OutOfOrder,
    Recorded,
    Repeated,
    RunEnded,
    RunStarted,
)
from opendnc.surface.grid import Grid, Units, parse_grid, parse_origin
from opendnc.surface.program import (
    ProbeMoves,
    SurfaceProgram,
    default_moves,
    generate,
    grid_from_program,
    parse_program_number,
)

app = typer.Typer(
    help="Probe a grid on a Haas, capture the DPRNT points, report flatness and tilt.",
    no_args_is_help=True,
)

GridOpt = typer.Option(None, "--grid", help="Points along X by Y, e.g. 10x10.")
PitchOpt = typer.Option(None, "--pitch", help="Spacing between points along X (and Y).")
PitchYOpt = typer.Option(None, "--pitch-y", help="Spacing along Y when it differs from X.")
OriginOpt = typer.Option("0,0", "--origin", help="X,Y of the first point (work coordinates).")
UnitsOpt = typer.Option("inch", "--units", help="Program units: inch (G20) or mm (G21).")


def _grid(
    grid: str | None, pitch: float | None, pitch_y: float | None, origin: str, units: str
) -> Grid:
    if grid is None or pitch is None:
        raise InputError("give --grid COLSxROWS and --pitch (or --program FILE for capture)")
    columns, rows = parse_grid(grid)
    ox, oy = parse_origin(origin)
    return Grid(
        columns, rows, pitch, pitch if pitch_y is None else pitch_y, ox, oy, Units.parse(units)
    )


def _moves(
    units: Units,
    clearance: float | None,
    approach: float | None,
    depth: float | None,
    feed: float | None,
) -> ProbeMoves:
    base = default_moves(units, clearance)
    return ProbeMoves(
        base.clearance,
        base.approach if approach is None else approach,
        base.depth if depth is None else depth,
        base.feed if feed is None else feed,
    )


def _program(
    grid: str | None,
    pitch: float | None,
    pitch_y: float | None,
    origin: str,
    units: str,
    clearance: float | None,
    approach: float | None,
    depth: float | None,
    feed: float | None,
    number: str,
    tool: int | None,
) -> SurfaceProgram:
    chosen = _grid(grid, pitch, pitch_y, origin, units)
    if clearance is None:
        raise InputError("give --clearance Z: the height that clears everything on the table")
    moves = _moves(chosen.units, clearance, approach, depth, feed)
    return generate(chosen, number=parse_program_number(number), moves=moves, tool=tool)


ClearanceOpt = typer.Option(None, "--clearance", help="Safe Z for moves between points (work Z).")
ApproachOpt = typer.Option(
    None, "--approach", help="Z where probing starts (default 0.1 in / 2.5 mm above Z0)."
)
DepthOpt = typer.Option(
    None, "--depth", help="How far below Z0 the probe may search (default as approach)."
)
FeedOpt = typer.Option(None, "--feed", help="Protected-move feed (default 30 in/min, 750 mm/min).")
NumberOpt = typer.Option("O01234", "--number", help="Program number (8000/9000 series refused).")
ToolOpt = typer.Option(None, "--tool", help="Probe tool number: adds T M06 and G43 H.")


@app.command("program")
def program_cmd(
    grid: str | None = GridOpt,
    pitch: float | None = PitchOpt,
    pitch_y: float | None = PitchYOpt,
    origin: str = OriginOpt,
    units: str = UnitsOpt,
    clearance: float | None = ClearanceOpt,
    approach: float | None = ApproachOpt,
    depth: float | None = DepthOpt,
    feed: float | None = FeedOpt,
    number: str = NumberOpt,
    tool: int | None = ToolOpt,
    output: Path | None = typer.Option(None, "--output", "-o", help="Write here (default stdout)."),
) -> None:
    """Write a Haas program that probes the grid (serpentine) and prints one DPRNT line a point."""
    with cli_errors():
        made = _program(
            grid, pitch, pitch_y, origin, units, clearance, approach, depth, feed, number, tool
        )
        if output is None:
            sys.stdout.write(made.text)
            return
        try:
            output.write_text(made.text, encoding="ascii")
        except OSError as exc:
            raise InputError(f"cannot write {output}: {exc.strerror or exc}") from None
        err_console.print(
            f"{made.name}: {made.grid.size} points, {len(made.text)} bytes -> {output}",
            highlight=False,
        )


def _show_event(event: MatchEvent, verbose: bool) -> None:
    if isinstance(event, Recorded):
        if verbose:
            p = event.point
            console.print(f"point {p.number} X{p.x:g} Y{p.y:g} Z{event.z:g}", highlight=False)
    elif isinstance(event, Missing):
        numbers = ", ".join(map(str, event.numbers))
        err_console.print(f"[yellow]missing:[/] point {numbers} (before {event.before})")
    elif isinstance(event, Repeated):
        how = "same value" if event.same else f"Z{event.z:g}, kept Z{event.stored:g}"
        err_console.print(f"[yellow]repeated:[/] point {event.number} ({how})")
    elif isinstance(event, OutOfOrder):
        err_console.print(f"[yellow]out of order:[/] point {event.number} after {event.after}")
    elif isinstance(event, Mismatch):
        err_console.print(f"[red]not stored:[/] {escape(event.reason)}: {escape(event.text)!r}")
    elif isinstance(event, RunStarted):
        err_console.print("[dim]program started (SURFACE START)[/]")
    elif isinstance(event, RunEnded):
        err_console.print("[dim]program ended (SURFACE END)[/]")


def _finish(report: CaptureReport, points: Path, as_json: bool) -> None:
    if as_json:
        print_json(report)
    missing = ", ".join(map(str, report.missing[:50])) + (
        " ..." if len(report.missing) > 50 else ""
    )
    err_console.print(
        f"{report.captured} of {report.total} points in {points}"
        + (f"; missing: {missing}" if report.missing else "")
        + (f" ({report.reason})" if report.reason else ""),
        highlight=False,
        soft_wrap=True,
    )
    if report.missing:
        raise typer.Exit(2)


@app.command("capture")
def capture_cmd(
    port: str = typer.Option(
        ..., "--port", help="Serial port / pyserial URL, or tcp://HOST:PORT (NGC Setting 263)."
    ),
    output: Path = typer.Option(..., "--output", "-o", help="Points CSV to write."),
    grid: str | None = GridOpt,
    pitch: float | None = PitchOpt,
    pitch_y: float | None = PitchYOpt,
    origin: str = OriginOpt,
    units: str = UnitsOpt,
    program: Path | None = typer.Option(
        None, "--program", help="Read the grid from the program `surface program` wrote."
    ),
    baud: int = typer.Option(9600, "--baud", help="Serial baud rate (Setting 11)."),
    jsonl: Path | None = typer.Option(None, "--jsonl", help="Also log every raw line here."),
    resume: bool = typer.Option(False, "--resume", help="Continue an interrupted capture file."),
    timeout: float | None = typer.Option(
        None, "--timeout", help="Give up after this many seconds without a line."
    ),
    verbose: bool = typer.Option(False, "--verbose", "-v", help="Print every point."),
    as_json: bool = typer.Option(False, "--json", help="Print the outcome as JSON."),
) -> None:
    """Capture the probing run's DPRNT lines into one CSV row per grid point.

    Exits 0 when every point is in the file, 2 when the run ended (or --timeout passed)
    with points missing.
    """
    from opendnc.surface.capture import capture

    with cli_errors():
        if program is not None:
            try:
                chosen = grid_from_program(program.read_text(encoding="ascii", errors="replace"))
            except OSError as exc:
                raise InputError(f"cannot read {program}: {exc.strerror or exc}") from None
        else:
            chosen = _grid(grid, pitch, pitch_y, origin, units)
        report = capture(
            port,
            chosen,
            output,
            baudrate=baud,
            resume=resume,
            jsonl=jsonl,
            idle_timeout=timeout,
            on_event=lambda event: _show_event(event, verbose),
            on_status=lambda message: err_console.print(f"[dim]{escape(message)}[/]"),
        )
        _finish(report, output, as_json)


def _need_extra() -> None:
    missing = [m for m in ("numpy", "matplotlib", "plotly") if importlib.util.find_spec(m) is None]
    if missing:
        raise InputError(
            f"the surface report needs {', '.join(missing)}: pip install 'opendnc[surface]'"
        )


def _print_summary(summary: dict[str, object], as_json: bool) -> None:
    if as_json:
        print_json(summary)
        return
    units = str(summary["units"])
    tilt = summary["tilt"]
    assert isinstance(tilt, dict)
    lines = [
        f"points     {summary['points']}"
        + (f" (missing {summary['missing']})" if summary["missing"] else ""),
        f"flatness   {summary['flatness']:.5f} {units} (peak to valley after plane removal)",
        f"rms        {summary['rms']:.5f} {units}",
    ]
    for axis in ("x", "y"):
        t = tilt[axis]
        lines.append(
            f"tilt {axis.upper()}     {t['rise']:+.5f} {units} per {t['per']} "
            f"({t['arcsec']:+.1f} arcsec)"
        )
    outliers = summary["outliers"]
    assert isinstance(outliers, list)
    lines.append(
        f"outliers   {len(outliers)}"
        + (": points " + ", ".join(str(o["point"]) for o in outliers[:20]) if outliers else "")
    )
    sys.stdout.write("\n".join(lines) + "\n")


@app.command("report")
def report_cmd(
    points: Path = typer.Argument(..., help="Points CSV (from `surface capture`, or any x,y,z)."),
    output: Path | None = typer.Option(None, "--output", "-o", help="Offline HTML report."),
    png: Path | None = typer.Option(None, "--png", help="Heat map with contours (PNG)."),
    stl: Path | None = typer.Option(None, "--stl", help="Measured surface as a binary STL."),
    units: str | None = typer.Option(
        None, "--units", help="inch or mm when the file does not say (default inch)."
    ),
    outlier_k: float = typer.Option(
        3.5, "--outlier-k", help="Outlier threshold in robust sigmas (1.4826 x MAD)."
    ),
    as_json: bool = typer.Option(False, "--json", help="Print the numbers as JSON."),
) -> None:
    """Fit the best plane; print tilt, flatness, RMS and outliers; write HTML/PNG/STL."""
    with cli_errors():
        _need_extra()
        from opendnc.surface.report import write_report

        report = write_report(
            points,
            output,
            png=png,
            stl=stl,
            units=Units.parse(units) if units else None,
            outlier_k=outlier_k,
        )
        _print_summary(report.summary(), as_json)


@app.command("measure")
def measure_cmd(
    haas: str = typer.Option(
        ..., "--haas", help="Serial port / URL of the control, or its host name (with --share)."
    ),
    grid: str | None = GridOpt,
    pitch: float | None = PitchOpt,
    pitch_y: float | None = PitchYOpt,
    origin: str = OriginOpt,
    units: str = UnitsOpt,
    clearance: float | None = ClearanceOpt,
    approach: float | None = ApproachOpt,
    depth: float | None = DepthOpt,
    feed: float | None = FeedOpt,
    number: str = NumberOpt,
    tool: int | None = ToolOpt,
    output: Path = typer.Option(Path("surface.html"), "--output", "-o", help="HTML report."),
    points: Path | None = typer.Option(
        None, "--points", help="Points CSV (default: next to the report, .csv)."
    ),
    png: Path | None = typer.Option(None, "--png", help="Also write the heat map PNG."),
    stl: Path | None = typer.Option(None, "--stl", help="Also write an STL of the surface."),
    share: str | None = typer.Option(
        None, "--share", help="Net Share folder or smb://user:pw@host/share to load the program."
    ),
    dprnt_port: int = typer.Option(5052, "--dprnt-port", help="DPRNT TCP port (Setting 263)."),
    baud: int = typer.Option(9600, "--baud", help="Serial baud rate (Setting 11)."),
    timeout: float | None = typer.Option(
        None, "--timeout", help="Give up after this many seconds without a line."
    ),
    resume: bool = typer.Option(False, "--resume", help="Continue an interrupted points file."),
    unsafe: bool = typer.Option(
        False, "--unsafe", help="Start the program by drip-feeding it (serial DNC): it moves."
    ),
    as_json: bool = typer.Option(False, "--json", help="Print the numbers as JSON."),
) -> None:
    """Generate, load, wait for cycle start (or drip-feed with --unsafe), capture, report."""
    from opendnc.surface.measure import MeasurePlan, measure

    with cli_errors():
        _need_extra()
        made = _program(
            grid, pitch, pitch_y, origin, units, clearance, approach, depth, feed, number, tool
        )
        points_path = points or output.with_suffix(".csv")
        plan = MeasurePlan(
            haas=haas,
            program=made,
            program_path=points_path.with_name(f"{made.name}.nc"),
            points=points_path,
            baud=baud,
            share=share,
            dprnt_port=dprnt_port,
            unsafe=unsafe,
            idle_timeout=timeout,
            resume=resume,
        )
        report = measure(
            plan,
            say=lambda message: err_console.print(escape(message), highlight=False, soft_wrap=True),
            on_event=lambda event: _show_event(event, False),
        )
        if report.captured < 3:
            _finish(report, points_path, False)
            raise InputError("fewer than 3 points captured: no report")
        from opendnc.surface.report import write_report

        built = write_report(points_path, output, png=png, stl=stl)
        _print_summary(built.summary(), as_json)
        err_console.print(f"report: {output}", highlight=False)
        if report.missing:
            _finish(report, points_path, False)
