"""README.md, followed in order, works: its shell and Python examples run against the simulators.

The rules a README section follows are in the module :mod:`tests.cli.readme_blocks` docstring
(fences that run, markers, background servers). The run happens under ``unshare`` with a
private loopback and a private ``/tmp``, so the README's literal ports and paths never meet
another test run. It runs in a fresh checkout (a git repository of this tree's files), which
must be as clean afterwards as before: the README's examples keep their files out of git's way.
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from tests import peers
from tests.cli.readme_blocks import (
    ALLOWED_FENCES,
    RUN_FENCES,
    Block,
    build_script,
    parse_readme,
    split_commands,
    unwaited_background_jobs,
)

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"
RUN_DEADLINE = 420.0  # seconds for the whole README: about 100 commands, 1-3 min on a busy machine
# <file>, HOST:PORT style words or [--optional] flags cannot run as typed
PLACEHOLDER = re.compile(r"(?<![<\d])<[A-Za-z][\w.-]*>|\[--")


def _blocks() -> list[Block]:
    return parse_readme(README.read_text(encoding="utf-8"))


def test_structure_fences_and_markers() -> None:
    blocks = _blocks()
    assert any(b.lang == "sh" and b.skip is None for b in blocks), "no runnable sh block found"
    for block in blocks:
        where = f"README.md:{block.line}"
        assert block.lang in ALLOWED_FENCES, (
            f"{where}: fence ```{block.lang}: use sh, python, text or a bare fence"
        )
        if block.skip is not None:
            assert block.skip.strip(), f"{where}: a skipped block needs a reason"
        if block.lang == "python":
            compile("\n".join(block.lines), where, "exec")


def test_structure_every_command_is_parsed() -> None:
    # a heredoc or line continuation the splitter misreads would silently run the wrong thing
    for block in _blocks():
        if block.lang != "sh" or block.skip is not None:
            continue
        commands = split_commands(block)
        text = "\n".join(block.lines)
        assert sum(len(c.text.split("\n")) for c in commands) == len(text.split("\n")), (
            f"README.md:{block.line}: lines lost while splitting the block"
        )
        for command in commands:
            if command.heredoc:
                continue
            code = command.text.split(" #", 1)[0]
            assert not PLACEHOLDER.search(code), (
                f"README.md:{command.line}: placeholder in a command that runs: {code.strip()}"
            )


def test_structure_every_background_job_is_waited_for() -> None:
    # pasted as one script, the line after `cmd &` runs at once: it must wait for cmd to listen
    for block in _blocks():
        if block.lang != "sh" or block.skip is not None:
            continue
        for command in unwaited_background_jobs(block):
            raise AssertionError(
                f"README.md:{command.line}: {command.text.strip()!r} starts a background job; "
                "follow it with `opendnc wait ...` (tcp://, http:// or the job's --ready-file)"
            )


def test_structure_every_curl_line_states_its_answer() -> None:
    checked = 0
    for block in _blocks():
        if block.lang != "sh" or block.skip is not None:
            continue
        for command in split_commands(block):
            if command.text.lstrip().startswith("curl "):
                assert "[prints " in command.text, (
                    f"README.md:{command.line}: a curl line says what it answers: [prints ...]"
                )
                checked += 1
    assert checked >= 5


def _fresh_checkout(target: Path) -> None:
    """``target`` as a fresh clone of this tree would be: its files, committed, nothing else."""
    git = peers.require_command("git")
    listed = subprocess.run(
        [git, "-C", str(ROOT), "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
        capture_output=True,
        check=True,
    ).stdout.split(b"\0")
    for name in filter(None, (n.decode() for n in listed)):
        source = ROOT / name
        if source.is_file():
            (target / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(source, target / name)
    ident = ["-c", "user.name=readme", "-c", "user.email=readme@localhost"]
    for step in (["init", "-q"], ["add", "-A"], [*ident, "commit", "-q", "-m", "snapshot"]):
        subprocess.run([git, *step], cwd=target, check=True, capture_output=True)


def _git_status(target: Path) -> str:
    return subprocess.run(
        ["git", "status", "--porcelain", "--untracked-files=all", "--ignored=no"],
        cwd=target,
        capture_output=True,
        text=True,
        check=True,
    ).stdout


def _isolation() -> list[str]:
    """``unshare`` arguments for a private loopback and /tmp: as root, else in a user namespace."""
    unshare = peers.require_command("unshare")
    peers.require_command("ip")
    private = ["--net", "--mount"]
    tries = [[unshare, *private], [unshare, "--user", "--map-root-user", *private]]
    if os.geteuid() != 0:
        tries.reverse()
    failures = []
    for base in tries:
        probe = subprocess.run(
            [*base, "sh", "-c", "ip link set lo up && mount -t tmpfs tmpfs /tmp"],
            capture_output=True,
            text=True,
            timeout=30,
        )
        if probe.returncode == 0:
            return base
        failures.append(probe.stderr.strip() or "refused")
    peers.missing_peer(f"unshare with a private network and /tmp ({'; '.join(failures)})")
    raise AssertionError("unreachable")


# the run's own deadline ends it with the README's output; pytest-timeout's 300 s would cut it
# short first, with nothing said (seen on a loaded machine)
@pytest.mark.timeout(RUN_DEADLINE + 60)
def test_readme_runs_in_order(tmp_path: Path) -> None:
    isolate = _isolation()
    blocks = _blocks()
    assert any(b.lang in RUN_FENCES and b.skip is None for b in blocks)
    private_tmp = tmp_path / "tmp"  # /tmp inside the run; the README runs in /tmp/work
    checkout = private_tmp / "work"
    checkout.mkdir(parents=True)
    _fresh_checkout(checkout)
    assert _git_status(checkout) == ""
    script = build_script(blocks, state_dir="/tmp/.readme-test")
    (tmp_path / "readme.sh").write_text(script, encoding="utf-8")

    env = {k: v for k, v in os.environ.items() if not k.startswith("OPENDNC_")}
    env.update(
        PATH=f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}",
        PYTHONUNBUFFERED="1",
        NO_COLOR="1",
        TERM="dumb",
        COLUMNS="120",
    )
    # A checkout (and its .venv) under /tmp would vanish behind the private /tmp: bind those
    # folders into it first, so `opendnc` and the sources stay where they are.
    keep = sorted(_host_tmp_folders(ROOT, Path(sys.executable).parent.absolute()))
    for name in keep:
        (private_tmp / name).mkdir(exist_ok=True)
    inner = (
        'p=$1; shift; for d in "$@"; do mount --bind "/tmp/$d" "$p/$d" || exit 1; done; '
        'mount --rbind "$p" /tmp && ip link set lo up && cd /tmp/work && exec bash -s'
    )
    proc = subprocess.Popen(
        [*isolate, "sh", "-c", inner, "sh", str(private_tmp), *keep],
        cwd=tmp_path,
        env=env,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
    )
    try:
        output, _ = proc.communicate(script, timeout=RUN_DEADLINE)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        output, _ = proc.communicate()
        pytest.fail(f"README run exceeded {RUN_DEADLINE:.0f} s\n{_tail(output, private_tmp)}")
    finally:
        with contextlib.suppress(ProcessLookupError):  # servers the README left running
            os.killpg(proc.pid, signal.SIGKILL)
    (tmp_path / "transcript.txt").write_text(output, encoding="utf-8")  # for a look afterwards
    assert proc.returncode == 0, f"README run failed\n{_tail(output, private_tmp)}"
    assert output.rstrip().endswith("README-DONE"), "the run stopped before the README's end"
    # the answers the README promises (each curl line's [prints ...]) were checked in the run;
    # its files stayed where git does not see them
    left = _git_status(checkout)
    assert left == "", f"following the README left files in the checkout:\n{left}"


def _host_tmp_folders(*paths: Path) -> set[str]:
    """The top-level folders of /tmp that hold any of ``paths``."""
    names = set()
    for path in paths:
        try:
            names.add(path.relative_to("/tmp").parts[0])
        except (ValueError, IndexError):
            continue
    return names


def _tail(output: str, private_tmp: Path) -> str:
    logs = []
    for log in sorted((private_tmp / ".readme-test").glob("*.log")):
        text = log.read_text(errors="replace")[-2000:]
        logs.append(f"--- background job from README.md:{log.stem}\n{text}")
    return output[-6000:] + "\n" + "\n".join(logs)
