"""`opendnc demo`: a live tour against virtual controls, with no setup.

Starts a virtual TNC 640 (and, when available, a virtual Haas) in this process on loopback
port 0, then talks to it with the same clients a user would point at a machine.
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import typer

from opendnc.cli.common import cli_errors, console
from opendnc.cli.lsv2_machine import _text as status_text  # the words `lsv2 status` uses
from opendnc.cli.lsv2_machine import machine_status
from opendnc.errors import DncError

if TYPE_CHECKING:  # the simulators, clients and rich's tables load when the tour runs
    from rich.table import Table

    from opendnc.lsv2 import Client

DEMO_PROGRAM = (
    "0 BEGIN PGM DEMO MM\r\n"
    "1 BLK FORM 0.1 Z X+0 Y+0 Z-20\r\n"
    "2 BLK FORM 0.2 X+100 Y+100 Z+0\r\n"
    "3 TOOL CALL 1 Z S4000 F800\r\n"
    "4 L Z+50 R0 FMAX M3\r\n"
    "5 L X+10 Y+10 R0 FMAX\r\n"
    "6 L Z-5 F200\r\n"
    "7 L X+90 RL F800\r\n"
    "8 L Y+90\r\n"
    "9 L X+10\r\n"
    "10 L Y+10\r\n"
    "11 L Z+50 R0 FMAX M30\r\n"
    "12 END PGM DEMO MM\r\n"
).encode("ascii")


def _kv(title: str, rows: Sequence[tuple[str, object]]) -> Table:
    from rich.table import Table

    table = Table(show_header=False, title=title, title_justify="left", title_style="bold")
    table.add_column(style="cyan")
    table.add_column()
    for key, value in rows:
        table.add_row(key, "n/a" if value is None else str(value))
    return table


def _tour_tnc(tnc: Client, workdir: Path) -> None:
    from rich.table import Table

    v = tnc.versions
    console.print(
        _kv(
            "Control",
            [
                ("model", v.model),
                ("family", tnc.family.value),
                ("NC software", v.nc_software),
                ("PLC software", v.plc),
                ("telegram buffer", f"{tnc.buffer_size} bytes"),
            ],
        )
    )

    listing = Table(title="TNC:\\nc_prog", title_justify="left", title_style="bold")
    listing.add_column("name")
    listing.add_column("size", justify="right")
    listing.add_column("modified")
    for entry in tnc.list_dir("TNC:/nc_prog"):
        listing.add_row(
            entry.name + ("\\" if entry.is_dir else ""),
            "" if entry.is_dir else f"{entry.size:,}",
            entry.modified.strftime("%Y-%m-%d %H:%M:%S"),
        )
    console.print(listing)

    local = workdir / "DEMO.H"
    local.write_bytes(DEMO_PROGRAM)
    started = time.perf_counter()
    tnc.upload(local, "TNC:/nc_prog/DEMO.H", binary=True)
    back = workdir / "DEMO_back.H"
    tnc.download("TNC:/nc_prog/DEMO.H", back, binary=True)
    elapsed = (time.perf_counter() - started) * 1000
    same = back.read_bytes() == DEMO_PROGRAM
    console.print(
        f"[bold]Round trip[/]: uploaded DEMO.H ({len(DEMO_PROGRAM)} bytes) and downloaded it "
        f"back in {elapsed:.1f} ms: "
        + ("[green]bytes identical[/]" if same else "[red]bytes DIFFER[/]")
    )
    if not same:
        raise typer.Exit(1)

    status = machine_status(tnc)
    word = tnc.read_plc("W4", 1)[0]
    console.print(
        _kv(
            "Machine",
            [
                ("execution mode", status["execution_mode"]),
                ("program state", status["program_state"]),
                ("selected program", status["selected_program"]),
                # shown as `opendnc lsv2 status` shows them: feed 100 %  spindle 100 % ...
                ("overrides", status_text(status["overrides"])),
                ("axes", status_text(status["axes"])),
                ("PLC word W4", word),
            ],
        )
    )

    tools = tnc.read_table()
    table = Table(
        title=f"Tool table {tools.name} ({len(tools.rows)} tools)",
        title_justify="left",
        title_style="bold",
    )
    shown = [c for c in ("T", "NAME", "L", "R", "DOC") if c in tools.column_names]
    for column in shown:
        table.add_column(column)
    for row in tools.rows[:6]:
        table.add_row(*(row.get(c, "") for c in shown))
    console.print(table)


def _tour_haas(workdir: Path) -> None:
    """Quick look at a virtual Haas over MDC; optional, so any failure is only reported."""
    try:
        from opendnc.haas.mdc_client import MdcClient
        from opendnc.sim.haas import HaasConfig, SimHaasThread, SimOptions
    except ImportError:
        return
    try:
        options = SimOptions(mdc_port=0)
        with SimHaasThread(HaasConfig(), workdir / "haas", options) as thread:
            sim = thread.sim
            assert sim is not None
            assert sim.mdc is not None
            with MdcClient("127.0.0.1", sim.mdc.port, timeout=3.0) as mdc:
                rows = [
                    (f"Q{code}", mdc.query(code).to_payload().strip()) for code in (100, 104, 500)
                ]
        console.print(_kv("Virtual Haas (MDC)", rows))
    except (DncError, OSError, AssertionError) as exc:
        console.print(f"[yellow]virtual Haas skipped:[/] {exc}", highlight=False)


def demo() -> None:
    """Start virtual controls and show what opendnc does with them."""
    from rich.panel import Panel

    from opendnc.lsv2 import Client
    from opendnc.sim.tnc import start_tnc

    with cli_errors(), tempfile.TemporaryDirectory(prefix="opendnc-demo-") as tmp:
        workdir = Path(tmp)
        console.print(Panel.fit("opendnc demo: virtual TNC 640 on 127.0.0.1 (LSV2)"))
        with start_tnc("tnc640", root=workdir / "tnc") as sim:
            console.print(f"virtual control listening on 127.0.0.1:{sim.port}", highlight=False)
            with Client("127.0.0.1", sim.port, timeout=5.0) as tnc:
                _tour_tnc(tnc, workdir)
        _tour_haas(workdir)
        console.print("[green]demo finished[/]")
