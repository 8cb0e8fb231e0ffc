"""`opendnc sim` commands: virtual controls and the virtual null-modem cable."""

from __future__ import annotations

import typer

from opendnc.cli import sim_cable, sim_fleet, sim_haas, sim_tnc

app = typer.Typer(
    help="Virtual controls and links for testing without a machine.", no_args_is_help=True
)
app.command("tnc")(sim_tnc.tnc)
app.command("cable")(sim_cable.cable)
app.command("haas")(sim_haas.haas)
app.command("fleet")(sim_fleet.fleet)
