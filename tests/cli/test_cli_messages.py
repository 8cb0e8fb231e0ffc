"""One-line errors that tell what to do (issue 23): an unknown profile lists the profiles, a
configuration error names the file."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from opendnc.sim.tnc import PROFILES

CLI = [sys.executable, "-m", "opendnc.cli.main"]


def run(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [*CLI, *args], capture_output=True, text=True, timeout=60, cwd=cwd, check=False
    )


@pytest.mark.parametrize(
    "args",
    [
        ["sim", "tnc", "--profile", "tnc999", "--port", "0"],
        ["sim", "fleet", "--profile", "tnc999", "--tnc", "1", "--haas", "0"],
    ],
    ids=["tnc", "fleet"],
)
def test_unknown_profile_lists_the_profiles(args: list[str], tmp_path: Path) -> None:
    done = run(*args, cwd=tmp_path)
    assert done.returncode == 1
    assert done.stderr == (
        f"error: unknown profile 'tnc999'; choose from {', '.join(PROFILES)}\n"
    ), done.stderr


@pytest.mark.parametrize(
    ("toml", "problem"),
    [
        ("[server]\nbind = \n", "not valid TOML: "),
        ("[server]\nbind = 7\n", "server.bind: "),
    ],
)
@pytest.mark.parametrize("command", [["serve"], ["keys", "create", "--role", "admin"]])
def test_a_configuration_error_names_the_file(
    tmp_path: Path, toml: str, problem: str, command: list[str]
) -> None:
    config = tmp_path / "shop.toml"
    config.write_text(toml)
    done = run(*command, "--config", str(config), cwd=tmp_path)
    assert done.returncode == 1
    assert done.stderr.startswith(f"error: {config}: {problem}"), done.stderr
    assert done.stderr.count("\n") == 1, done.stderr


@pytest.mark.parametrize("missing", ["fastapi", "sqlalchemy"])
@pytest.mark.parametrize("command", [["serve"], ["keys", "create", "--role", "admin"]])
def test_a_missing_server_extra_is_one_line_naming_it(
    tmp_path: Path, missing: str, command: list[str]
) -> None:
    config = tmp_path / "shop.toml"
    config.write_text('[server]\ndatabase = "sqlite:///x.db"\n')
    # None in sys.modules is how Python marks a module that cannot be imported
    hide = (
        f"import sys; sys.modules[{missing!r}] = None; sys.argv = ['opendnc', *sys.argv[1:]]; "
        "from opendnc.cli.main import app; app()"
    )
    done = subprocess.run(
        [sys.executable, "-c", hide, *command, "--config", str(config)],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=tmp_path,
        check=False,
    )
    assert done.returncode == 1
    assert done.stderr == (
        f"error: the server needs the 'server' extra ({missing} is missing): "
        "pip install 'opendnc[server]'\n"
    ), done.stderr
    assert not (tmp_path / "x.db").exists()
