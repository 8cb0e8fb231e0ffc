"""Turn README.md into one bash session (the rules: /work/wt/README-CONVENTION.md, summarised).

- ```` ```sh ```` and ```` ```python ```` blocks run, top to bottom, in one bash session
  (``cd``, variables and ``&`` jobs carry over); ```` ```text ```` and bare fences do not.
- ``<!-- readme-test: skip: REASON -->`` on the line before a fence skips that block.
- A trailing ``# ... [exit N]`` expects exit status N; ``# ... [not run]`` shows a line only;
  ``# ... [prints TEXT]`` expects TEXT in what the command prints on stdout.
- A line ending in ``&`` starts a background job whose output goes to a log. The run does not
  wait for it: the README itself must, as a person pasting it would need, so the next command
  is ``opendnc wait ...`` (or a command that waits by itself, see :data:`SELF_WAITING`).
- Python blocks run with the venv's python at their place in the order, in the same folder.
"""

from __future__ import annotations

import re
import shlex
import subprocess
from dataclasses import dataclass, field

RUN_FENCES = frozenset({"sh", "python"})
ALLOWED_FENCES = frozenset({"sh", "python", "text", ""})
#: Commands that may follow a background job because they wait for it themselves: `opendnc
#: wait`, the shell's `wait` for a job, and an XModem sender (it waits for the receiver's start
#: request up to its --timeout).
SELF_WAITING = ("opendnc wait ", "wait $", "opendnc xmodem send ")

_FENCE = re.compile(r"^```(\S*)\s*$")
_SKIP = re.compile(r"^<!--\s*readme-test:\s*skip:?\s*(.*?)\s*-->\s*$")
_EXIT = re.compile(r"\[exit (\d+)\]")
_PRINTS = re.compile(r"\[prints (.+?)\]")
_HEREDOC = re.compile(r"<<-?\s*(['\"]?)(\w+)\1")


@dataclass
class Block:
    """A fenced block: its language, the README line of its first content line, its lines."""

    lang: str
    line: int
    lines: list[str] = field(default_factory=list)
    skip: str | None = None


@dataclass
class Command:
    """One logical shell command (continuations and heredocs joined) and its README line."""

    line: int
    text: str
    heredoc: bool = False


def parse_readme(text: str) -> list[Block]:
    """Every fenced block of ``text`` with its skip marker."""
    blocks: list[Block] = []
    current: Block | None = None
    previous = ""
    for number, raw in enumerate(text.splitlines(), start=1):
        if current is None:
            match = _FENCE.match(raw)
            if match:
                skip = _SKIP.match(previous)
                current = Block(match.group(1), number + 1, skip=skip.group(1) if skip else None)
            previous = raw
            continue
        if raw.startswith("```"):
            blocks.append(current)
            current = None
            previous = raw
            continue
        current.lines.append(raw)
    if current is not None:
        raise ValueError(f"README.md:{current.line - 1}: fence never closed")
    return blocks


def _code_part(line: str) -> str:
    """``line`` without its trailing comment (a ``#`` after a blank, outside quotes)."""
    quote = ""
    for index, char in enumerate(line):
        if quote:
            if char == quote:
                quote = ""
        elif char in "'\"":
            quote = char
        elif char == "#" and (index == 0 or line[index - 1] in " \t"):
            return line[:index]
    return line


def _complete(text: str) -> bool:
    """True if bash can parse ``text`` on its own (no open quote, group, loop or heredoc)."""
    probe = text + ("\n" if not text.endswith("\n") else "")
    result = subprocess.run(["bash", "-n"], input=probe, capture_output=True, text=True)
    return result.returncode == 0 and not result.stderr  # an open heredoc only warns


def _continued(text: str) -> bool:
    return _code_part(text.split("\n")[-1]).rstrip().endswith("\\")


def split_commands(block: Block) -> list[Command]:
    """Logical commands of a sh block: the shortest runs of lines that bash parses alone."""
    commands: list[Command] = []
    lines = block.lines
    i = 0
    while i < len(lines):
        start = i
        text = lines[i]
        while (_continued(text) or not _complete(text)) and i + 1 < len(lines):
            i += 1
            text += "\n" + lines[i]
        heredoc = _HEREDOC.search(_code_part(text.split("\n", 1)[0])) is not None
        commands.append(Command(block.line + start, text, heredoc))
        i += 1
    return commands


def is_background(command: Command) -> bool:
    """True for a command that starts a background job (a line ending in ``&``)."""
    code = _code_part(_last(command.text)).rstrip()
    return not command.heredoc and code.endswith("&") and not code.endswith("&&")


def unwaited_background_jobs(block: Block) -> list[Command]:
    """Background jobs not followed by a command that waits for them (see SELF_WAITING); an
    assignment of ``$!`` in between is allowed."""
    commands = [
        c for c in split_commands(block) if c.text.strip() and not c.text.lstrip().startswith("#")
    ]
    bad = []
    for index, command in enumerate(commands):
        if not is_background(command):
            continue
        rest = commands[index + 1 :]
        while rest and re.fullmatch(r"\w+=\$!", rest[0].text.strip()):
            rest = rest[1:]
        if not rest or not rest[0].text.lstrip().startswith(SELF_WAITING):
            bad.append(command)
    return bad


def _last(text: str) -> str:
    return text.split("\n")[-1]


def _comment(text: str) -> str:
    last = _last(text)
    return last[len(_code_part(last)) :]


def _shell(block: Block, state_dir: str) -> list[str]:
    out: list[str] = []
    for command in split_commands(block):
        code = _code_part(_last(command.text))
        comment = _comment(command.text)
        shown = command.text.split("\n", 1)[0]
        if not command.text.strip() or command.text.lstrip().startswith("#"):
            out.append(command.text)
            continue
        out.append(f"__line={command.line}")
        out.append(f"__show {shlex.quote(f'README.md:{command.line}: {shown}')}")
        if "[not run]" in comment:
            continue
        expected = _EXIT.search(comment)
        prints = _PRINTS.search(comment)
        lines = command.text.split("\n")
        body = "\n".join([*lines[:-1], code.rstrip()])  # without the trailing comment
        if is_background(command):
            head = body.rstrip()[:-1].rstrip()
            log = f"{state_dir}/{command.line}.log"
            out.append(f"{head} > {log} 2>&1 &")  # no wait here: the README must wait
        elif prints is not None:
            want = shlex.quote(prints.group(1))
            out.append(f"__out=$({body})")
            out.append("printf '%s\\n' \"$__out\"")
            out.append(
                f'[[ "$__out" == *{want}* ]] || {{ echo "README.md:{command.line}: '
                f'expected the output to contain "{want} >&2; exit 1; }}'
            )
        elif expected is not None:
            out.append(f"__rc=0; {body} || __rc=$?")
            want = expected.group(1)
            out.append(
                f'[ "$__rc" = {want} ] || {{ echo "README.md:{command.line}: '
                f'expected exit status {want}, got $__rc" >&2; exit 1; }}'
            )
        else:
            out.append(body)
    return out


def _python(block: Block, state_dir: str) -> list[str]:
    path = f"{state_dir}/block-{block.line}.py"
    return [
        f"__line={block.line}",
        f"__show 'README.md:{block.line}: python block'",
        f"cat > {path} <<'__README_PYTHON__'",
        *block.lines,
        "__README_PYTHON__",
        f"python {path}",
    ]


PRELUDE = """\
set -e -o pipefail
__line=0
__t0=${EPOCHREALTIME/./}
__show() {  # "+ 12.3s README.md:LINE: command" before each command
  local us=$(( ${EPOCHREALTIME/./} - __t0 ))
  printf '+ %d.%ds %s\\n' $((us / 1000000)) $((us % 1000000 / 100000)) "$1"
}
trap 'echo "README.md:$__line: exit status $?" >&2' ERR
__stop() { local p; p=$(jobs -p); if [ -n "$p" ]; then kill $p 2>/dev/null || true; fi; }
trap __stop EXIT
"""


def build_script(blocks: list[Block], state_dir: str) -> str:
    """One bash script that runs every runnable block in order."""
    out = [PRELUDE, f"mkdir -p {state_dir}"]
    for block in blocks:
        if block.skip is not None or block.lang not in RUN_FENCES:
            continue
        if block.lang == "sh":
            out.extend(_shell(block, state_dir))
        else:
            out.extend(_python(block, state_dir))
    out.append("echo README-DONE")
    return "\n".join(out) + "\n"
