"""What every `opendnc` command shares: option placement, one-line errors, locked actions."""

from __future__ import annotations

import json
import os
import shlex
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from typer.testing import CliRunner

from opendnc.cli import clicklib as click
from opendnc.cli.lazy import GLOBAL_OPTIONS, place_global_options
from opendnc.cli.main import COMMANDS, app
from opendnc.sim.tnc import start_tnc

CLI = [sys.executable, "-m", "opendnc.cli.main"]
VALUES = {"--host": "127.0.0.1", "-H": "127.0.0.1", "--port": "7", "-p": "7", "--timeout": "2"}


def _root() -> tuple[click.Command, click.Context]:
    root = __import__("typer").main.get_command(app)
    return root, root.make_context("opendnc", ["--help"], resilient_parsing=True)


def _leaves(
    command: click.Command, ctx: click.Context, path: list[str]
) -> Iterator[tuple[list[str], list[click.Command]]]:
    if hasattr(command, "list_commands"):
        for name in command.list_commands(ctx):  # type: ignore[attr-defined]
            sub = command.get_command(ctx, name)  # type: ignore[attr-defined]
            for leaf_path, chain in _leaves(sub, ctx, [*path, name]):
                yield leaf_path, [command, *chain]
    else:
        yield path, [command]


def _declared(chain: list[click.Command]) -> set[str]:
    names: set[str] = set()
    for command in chain:
        for param in command.params:
            if getattr(param, "param_type_name", "") == "option":
                names.update(set(param.opts) & GLOBAL_OPTIONS)
    return names


def test_every_group_is_reachable_and_listed_without_import() -> None:
    result = subprocess.run(
        [
            *CLI[:1],
            "-c",
            "import sys; from opendnc.cli.main import app\n"
            "try:\n    app(['--help'])\nexcept SystemExit:\n    pass\n"
            "print(sorted(m for m in sys.modules if m.startswith('opendnc.cli.')))",
        ],
        capture_output=True,
        text=True,
        check=True,
    )
    loaded = result.stdout.strip().splitlines()[-1]
    for name in COMMANDS:
        assert name in result.stdout  # listed in the help
        assert f"opendnc.cli.{name}'" not in loaded  # but not imported for it


def test_global_options_land_in_the_same_place_before_or_after_the_subcommand() -> None:
    root, ctx = _root()
    checked = 0
    for path, chain in _leaves(root, ctx, []):
        for option in sorted(_declared(chain)):
            given = [option, VALUES[option]] if option in VALUES else [option]
            before = place_global_options(root, ctx, [*path[:1], *given, *path[1:]])
            after = place_global_options(root, ctx, [*path, *given])
            assert before == after, f"{' '.join(path)} {option}"
            checked += 1
    # lsv2 alone has 5 globals on ~25 commands; all groups together many more
    assert checked > 100


def test_global_option_moves_to_the_command_that_declares_it() -> None:
    root, ctx = _root()
    assert place_global_options(root, ctx, ["lsv2", "info", "--host", "h", "--json"]) == [
        "lsv2",
        "--host",
        "h",
        "info",
        "--json",
    ]
    assert place_global_options(root, ctx, ["haas", "--host", "h", "q", "Q500"]) == [
        "haas",
        "q",
        "--host",
        "h",
        "Q500",
    ]
    # an option after `--` is an argument
    assert place_global_options(root, ctx, ["lsv2", "rm", "--", "--json"]) == [
        "lsv2",
        "rm",
        "--",
        "--json",
    ]


@pytest.fixture(scope="module")
def tnc() -> Iterator[int]:
    with start_tnc("tnc640") as handle:
        yield handle.port


def _run(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("OPENDNC_")}
    env["COLUMNS"] = "200"
    return subprocess.run(
        [*CLI, *args], capture_output=True, text=True, timeout=60, env=env, cwd=cwd
    )


def test_options_before_and_after_give_the_same_answer(tnc: int) -> None:
    after = _run("lsv2", "ls", "TNC:/nc_prog", "--port", str(tnc), "--json", "--timeout", "5")
    before = _run("lsv2", "--port", str(tnc), "--json", "ls", "TNC:/nc_prog")
    assert after.returncode == 0, after.stderr
    assert json.loads(after.stdout) == json.loads(before.stdout)
    assert any(e["name"] == "POCKET.H" for e in json.loads(after.stdout))


@pytest.mark.parametrize(
    "args",
    [
        ["lsv2", "info", "--bogus"],
        ["lsv2", "--port", "x", "info"],
        ["lsv2", "lss"],
        ["haas", "q"],
        ["nosuch"],
        ["xmodem", "send", "missing.nc", "--port", "/dev/null"],
        ["xmodem", "send", "--port", "/dev/null"],
        ["xmodem", "recv", "out", "--port", "p", "--mode", "bad"],
        ["sim", "tnc", "--bogus"],
        ["lsv2", "--timeout", "soon", "info"],
    ],
)
def test_usage_errors_are_one_line_with_status_2(args: list[str]) -> None:
    result = _run(*args)
    assert result.returncode == 2, result.stderr
    assert result.stdout == ""
    lines = result.stderr.splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith("error: ")
    assert "--help" in lines[0]
    # click's own messages in our style: lower case, no sentences ending in full stops
    message = lines[0].removeprefix("error: ").split(" (see '", 1)[0]
    assert message[0].islower(), message
    assert ". " not in message, message
    assert not message.endswith("."), message


def test_a_locked_action_prints_the_exact_line_that_runs_it(tnc: int) -> None:
    name = "CfgDisplayLanguage.ncLanguage"
    refused = _run("lsv2", "param", "set", name, "GERMAN", "--port", str(tnc))
    assert refused.returncode == 1
    assert len(refused.stderr.splitlines()) == 1, refused.stderr
    line = refused.stderr.split("to run it: ", 1)[1].strip()
    argv = shlex.split(line)
    assert "--unsafe" in argv
    # run as `python -m opendnc.cli.main` here, so that is the program named in the hint
    assert argv[:3] == ["python", "-m", "opendnc.cli.main"], line
    allowed = _run(*argv[3:])
    assert allowed.returncode == 0, allowed.stderr
    got = _run("lsv2", "--port", str(tnc), "param", "get", name)
    assert got.stdout.strip() == "GERMAN"


def test_xmodem_send_and_recv_default_to_checksum() -> None:
    root, ctx = _root()
    group = root.get_command(ctx, "xmodem")  # type: ignore[attr-defined]
    defaults = {}
    for verb in ("send", "recv"):
        command = group.get_command(ctx, verb)
        defaults[verb] = next(p.default for p in command.params if p.name == "mode")
    assert defaults["send"] == defaults["recv"]
    assert getattr(defaults["send"], "value", defaults["send"]) == "checksum"


def test_recv_into_a_missing_folder_is_an_error(tmp_path: Path) -> None:
    result = _run("xmodem", "recv", "missing/", "--port", "/dev/null", cwd=tmp_path)
    assert result.returncode == 1
    assert "folder missing/ does not exist" in result.stderr
    assert list(tmp_path.iterdir()) == []


def test_no_click_traceback_on_a_bad_value() -> None:
    result = CliRunner().invoke(app, ["lsv2", "--timeout", "soon", "info"])
    assert result.exit_code == 2
    assert "Traceback" not in result.output


def _modules_after(*args: str) -> set[str]:
    code = (
        "import sys\nfrom opendnc.cli.main import app\n"
        f"try:\n    app({list(args)!r})\nexcept SystemExit:\n    pass\n"
        "print(' '.join(sorted(sys.modules)))"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=60
    )
    return set(result.stdout.splitlines()[-1].split())


@pytest.mark.parametrize(
    "args",
    [
        ["--help"],
        ["lsv2", "--help"],
        ["lsv2", "table", "get", "--help"],
        ["haas", "q", "--help"],
        ["xmodem", "send", "--help"],
        ["dprnt", "--help"],
        ["sim", "tnc", "--help"],
        ["demo", "--help"],
    ],
)
def test_help_loads_no_protocol_stack(args: list[str]) -> None:
    # the costly parts: the LSV2 client stack, the simulators, asyncio clients, rich's renderers
    loaded = _modules_after(*args)
    heavy = {
        "opendnc.lsv2.client",
        "opendnc.sim.tnc",
        "opendnc.sim.haas",
        "opendnc.haas.mdc_client",
        "opendnc.xmodem.files",
        "rich.progress",
        "rich.table",
        "typer.rich_utils",
    }
    assert "opendnc.cli.main" in loaded
    assert not heavy & loaded, sorted(heavy & loaded)


def test_names_kept_for_help_match_the_modules_they_stand_for() -> None:
    from opendnc.cli import haas, sim_tnc
    from opendnc.haas import mdc_client
    from opendnc.sim.tnc import PROFILES

    assert tuple(PROFILES) == sim_tnc.PROFILE_NAMES
    assert haas.DEFAULT_PORT == mdc_client.DEFAULT_PORT


def test_shell_completion_reaches_lazy_groups() -> None:
    env = dict(os.environ, _OPENDNC_COMPLETE="complete_bash", COMP_WORDS="opendnc lsv2 l")
    env["COMP_CWORD"] = "2"
    code = "import sys; sys.argv[0] = 'opendnc'; from opendnc.cli.main import app; app()"
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=60
    )
    assert result.stdout.split() == ["ls", "log"]


def test_a_command_help_names_the_group_options_it_accepts() -> None:
    result = CliRunner().invoke(app, ["lsv2", "info", "--help"])
    assert result.exit_code == 0
    note = result.output.split("Also accepted here", 1)[1]
    for option in ("--host", "--port", "--timeout", "--unsafe"):
        assert option in note
    assert "--json" not in note  # info declares its own
