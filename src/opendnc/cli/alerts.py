"""``opendnc alerts test``: send a test alert to the targets of ``[alerts]`` and say how each
went, to check an SMTP login or a webhook before a machine needs it (docs/server.md#alerts)."""

from __future__ import annotations

from pathlib import Path

import typer

from opendnc.cli.common import cli_errors, console
from opendnc.cli.serve import ConfigOption, require_server_extra
from opendnc.errors import InputError

app = typer.Typer(help="Alerts by e-mail and webhook ([alerts]).", no_args_is_help=True)


@app.command("test")
def send_test(
    config: Path = ConfigOption,
    machine: str | None = typer.Option(
        None, "--machine", help="The machine the message names (default: the first)."
    ),
    to: list[str] | None = typer.Option(
        None, "--to", help="A target's name (email, or a webhook's); default every target."
    ),
) -> None:
    """Send one test alert ("in alarm") to every target now; exit 1 if one failed."""
    with cli_errors():
        require_server_extra()
        import asyncio

        from opendnc.server.alerts.component import Alerts
        from opendnc.server.config.shop import load_config
        from opendnc.server.core.events import EventBus

        shop = load_config(config)
        if shop.alerts is None:
            raise InputError(f"{config}: no [alerts] table")
        names = {t.name for t in shop.alerts.targets}
        chosen = tuple(to or ())
        for name in chosen:
            if name not in names:
                raise InputError(f"no target {name!r} (have {', '.join(sorted(names))})")
        if machine is None:
            machine = shop.machines[0].name if shop.machines else "test"
        part = Alerts(shop.alerts, EventBus(), None, shop.calendar, shop.server.name)
        deliveries = asyncio.run(part.send_test(machine, chosen))
    for delivery in deliveries:
        if delivery.sent:
            console.print(f"sent    {delivery.target}", highlight=False)
        else:
            console.print(f"failed  {delivery.target}: {delivery.error}", highlight=False)
    if not all(d.sent for d in deliveries):
        raise typer.Exit(1)
