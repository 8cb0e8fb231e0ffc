"""Entry point: ``opendnc <group> <command>``.

Adding a command group (or a top-level command)
-----------------------------------------------
Write it in its own module with a ``typer.Typer`` named ``app`` (or a plain function for a
single command) and add ONE line to :data:`COMMANDS`::

    "surface": Lazy("opendnc.cli.surface:app", "Surface models from probe data."),

The module is imported only when its name is on the command line (or for shell completion);
``opendnc --help`` shows the one-line help given here. Keep the module's own top-level imports
to what its commands need, and import heavy libraries inside the command that uses them, so
``opendnc <group> --help`` stays fast too (``benchmarks/cli_startup.py`` measures it; the
target is at most 2x the import time of typer and rich). A group with many heavy subcommands
can be lazy itself: ``app = lazy_typer("help", {"name": Lazy("module:attr", "help")})``, as
:mod:`opendnc.cli.sim` does.

Conventions every command gets from :class:`~opendnc.cli.lazy.RootGroup`:

- ``--host -H --port -p --timeout --json --unsafe`` work before or after the subcommand, as
  long as the group or the command declares them (declare them where they mean something);
- usage errors and failures are one line on stderr (``error: ...``), exit status 2 and 1;
- run command bodies under :func:`opendnc.cli.common.cli_errors`: a
  :class:`~opendnc.errors.SafetyLockError` then prints the exact command line with
  ``--unsafe`` that would run the refused action.
"""

from __future__ import annotations

import typer

from opendnc import __version__
from opendnc.cli.lazy import Lazy, lazy_typer

#: Top-level command groups and commands, in ``--help`` order, imported on first use.
COMMANDS: dict[str, Lazy] = {
    "lsv2": Lazy("opendnc.cli.lsv2:app", "Heidenhain controls over LSV2 (TCP)."),
    "sim": Lazy("opendnc.cli.sim:app", "Virtual controls and links for testing without a machine."),
    "xmodem": Lazy("opendnc.cli.xmodem:app", "XModem transfers (Haas RS-232)."),
    "haas": Lazy("opendnc.cli.haas:app", "Haas controls: MDC queries, macro variables, Net Share."),
    "dprnt": Lazy("opendnc.cli.dprnt:app", "Capture DPRNT output from a Haas."),
    "serial": Lazy(
        "opendnc.cli.serial:app", "Tape code over RS-232 for any control (Fanuc, Siemens, ...)."
    ),
    "heidenhain": Lazy(
        "opendnc.cli.heidenhain:app", "Heidenhain blockwise (FE) file transfer over RS-232."
    ),
    "surface": Lazy("opendnc.cli.surface:app", "Probe a surface, capture it, report it."),
    "check": Lazy("opendnc.cli.check:check", "Dry-run an NC program: problems, tools, time."),
    "serve": Lazy("opendnc.cli.serve:serve", "Run the DNC server for the machines of a config."),
    "keys": Lazy("opendnc.cli.serve:keys_app", "API keys of the DNC server."),
    "users": Lazy("opendnc.cli.serve:users_app", "People who log in to the DNC server."),
    "requests": Lazy(
        "opendnc.cli.serve:requests_app", "Remote-request rules: test which rule takes a request."
    ),
    "wait": Lazy(
        "opendnc.cli.wait:wait", "Wait until servers listen or files exist (for scripts)."
    ),
    "cluster": Lazy(
        "opendnc.cli.cluster:app", "Several servers on one database: servers and their machines."
    ),
    "alerts": Lazy("opendnc.cli.alerts:app", "Alerts by e-mail and webhook: send a test."),
    "demo": Lazy(
        "opendnc.cli.demo_server:demo",
        "The DNC server with a virtual shop floor (--tour: a short command-line tour).",
    ),
}

app = lazy_typer(
    "Open DNC toolkit: talk to CNC controls, simulate them, move programs.", COMMANDS, root=True
)


@app.command("version")
def version() -> None:
    """Print the opendnc version."""
    typer.echo(__version__)


if __name__ == "__main__":
    app()
