"""Start-up time of the `opendnc` command against the import time of typer and rich.

Every command line is run as a fresh interpreter; the figure is the best of N runs (the least
disturbed by other load) minus a bare interpreter's start. Two references:

- ``import typer, rich.console``: the import time of typer and rich, the issue's yardstick
  (target, issue 10: the CLI adds at most 2x that);
- a one-command typer app printing its ``--help``: what typer itself costs to show any
  command (typer >= 0.2x builds each command's parameters with pydantic, ~60 ms, whatever the
  application does).

    .venv/bin/python benchmarks/cli_startup.py            # every command's --help
    .venv/bin/python benchmarks/cli_startup.py --quick    # top level and groups only
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time

RUN_CLI = "import sys; sys.argv[0] = 'opendnc'; from opendnc.cli.main import app; app()"
MINIMAL_APP = """
import typer, rich.console
app = typer.Typer()
@app.command()
def hello(name: str = typer.Option("world", "--name", help="Who.")) -> None:
    \"\"\"Say hello.\"\"\"
app()
"""
TARGET = 2.0


def best_of(argv: list[str], runs: int) -> float:
    """Shortest wall time of ``runs`` runs of ``argv``, in seconds."""
    best = float("inf")
    for _ in range(runs):
        started = time.perf_counter()
        subprocess.run(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=False)
        best = min(best, time.perf_counter() - started)
    return best


def command_lines(quick: bool) -> list[list[str]]:
    """``--help`` of the top level, every group and (unless quick) every command."""
    import typer

    from opendnc.cli.main import app

    root = typer.main.get_command(app)
    ctx = root.make_context("opendnc", ["--help"], resilient_parsing=True)
    lines: list[list[str]] = [["--help"]]

    def walk(command: object, path: list[str]) -> None:
        if not hasattr(command, "list_commands"):
            if not quick:
                lines.append([*path, "--help"])
            return
        if path:
            lines.append([*path, "--help"])
        for name in command.list_commands(ctx):
            walk(command.get_command(ctx, name), [*path, name])  # type: ignore[attr-defined]

    walk(root, [])
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=7, help="runs per command line (best kept)")
    parser.add_argument("--quick", action="store_true", help="top level and groups only")
    args = parser.parse_args()

    python = sys.executable
    bare = best_of([python, "-c", "pass"], args.runs)
    reference = best_of([python, "-c", "import typer, rich.console"], args.runs) - bare
    minimal = best_of([python, "-c", MINIMAL_APP, "--help"], args.runs) - bare
    print(
        f"python start {bare * 1000:.0f} ms; import typer + rich {reference * 1000:.0f} ms; "
        f"one-command typer app --help {minimal * 1000:.0f} ms"
    )
    print(f"{'command':40} {'added ms':>9} {'x import':>9} {'x app':>6}")
    worst = ("", 0.0, 0.0)
    for line in command_lines(args.quick):
        added = best_of([python, "-c", RUN_CLI, *line], args.runs) - bare
        text = "opendnc " + " ".join(line)
        ratio, ratio_app = added / reference, added / minimal
        print(f"{text:40} {added * 1000:9.0f} {ratio:9.2f} {ratio_app:6.2f}")
        if ratio > worst[1]:
            worst = (text, ratio, ratio_app)
    verdict = "within" if worst[1] <= TARGET else "ABOVE"
    print(
        f"worst: {worst[0]}: {worst[1]:.2f}x the typer + rich import ({verdict} the "
        f"{TARGET:.0f}x target), {worst[2]:.2f}x a one-command typer app"
    )


if __name__ == "__main__":
    main()
