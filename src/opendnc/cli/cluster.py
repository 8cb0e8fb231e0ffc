"""``opendnc cluster status``: the servers sharing one database, their heartbeats and leases."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.table import Table

from opendnc.cli.common import cli_errors, console, print_json
from opendnc.cli.serve import ConfigOption, DbOption, require_server_extra

app = typer.Typer(help="Several servers on one PostgreSQL database.", no_args_is_help=True)


@app.command("status")
def status(
    config: Path = ConfigOption,
    db: str | None = DbOption,
    json_out: bool = typer.Option(False, "--json", help="Print a JSON object."),
) -> None:
    """Servers, their heartbeats and the machines each one serves."""
    with cli_errors():
        require_server_extra()
        from opendnc.server.config.shop import load_config
        from opendnc.server.machines.leases import cluster_view
        from opendnc.server.store.db import make_engine, make_sessions, migrate

        shop = load_config(config)
        engine = make_engine(db or shop.server.database)
        try:
            migrate(engine)
            view = cluster_view(make_sessions(engine, reads_only=True))
        finally:
            engine.dispose()
    if json_out:
        from opendnc.server.actions.models import ClusterOut

        # the very document GET /api/cluster answers
        print_json(ClusterOut.of(view).model_dump(mode="json"))
        return
    servers = Table("server", "host", "pid", "address", "heartbeat", "machines", box=None)
    for row in view.servers:
        age = f"{row.heartbeat_age:.1f} s ago" + ("" if row.alive else " (gone)")
        servers.add_row(row.name, row.host, str(row.pid), row.url or "-", age, str(row.machines))
    console.print(servers if view.servers else "no server has joined this database")
    unserved = sorted(row.machine for row in view.leases if not row.live)
    duties = [row.owner for row in view.leases if row.machine == "@library" and row.live]
    if duties:
        console.print(f"library watcher and net share: {duties[0]}", highlight=False)
    if unserved:
        console.print(f"not served now: {', '.join(unserved)}", highlight=False)
