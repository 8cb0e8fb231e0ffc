"""Generate the blocking LSV2 client (``lsv2/client.py``) from the asyncio one (``lsv2/aio.py``).

Both facades are thin layers over the same sans-IO operations; one is written by hand and the
other derived, so they cannot drift apart. This tool lives outside the package (it does not
ship in the wheel) and formats its output with the ruff version pinned in ``pyproject.toml``
(``dev`` extra), because another formatter version could lay the same code out differently.

    python tools/unasync.py            # rewrite client.py after editing aio.py
    python tools/unasync.py --check    # exit 1 if client.py is stale (a unit test runs this)
"""

from __future__ import annotations

import re
import subprocess
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = ROOT / "src" / "opendnc" / "lsv2"
SOURCE = PACKAGE / "aio.py"
TARGET = PACKAGE / "client.py"

_HEADER = "# Generated from aio.py by tools/unasync.py; edit aio.py, then regenerate.\n"

_RULES: list[tuple[str, str]] = [
    (r"\basync with\b", "with"),
    (r"\basync def\b", "def"),
    (r"\bawait\s+", ""),
    (r"\bAsyncClient\b", "Client"),
    (r"\bAsyncDriver\b", "BlockingDriver"),
    (r"\b__aenter__\b", "__enter__"),
    (r"\b__aexit__\b", "__exit__"),
    (r"LSV2 client for asyncio", "Blocking LSV2 client"),
]


class GenerateError(Exception):
    """The output cannot be produced faithfully (wrong formatter, formatter failed)."""


def pinned_ruff() -> str:
    """The ruff version the ``dev`` extra pins (``ruff==X.Y.Z``)."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    for requirement in project["project"]["optional-dependencies"]["dev"]:
        name, sep, version = requirement.replace(" ", "").partition("==")
        if name == "ruff" and sep:
            return version
    raise GenerateError("pyproject.toml: the dev extra must pin ruff==X.Y.Z")


def _ruff(*args: str, stdin: str | None = None) -> str:
    done = subprocess.run(
        [sys.executable, "-m", "ruff", *args],
        input=stdin,
        capture_output=True,
        text=True,
        check=False,
        cwd=ROOT,
    )
    if done.returncode != 0:
        raise GenerateError(f"ruff {args[0]} failed: {done.stderr.strip()}")
    return done.stdout


def generate(source: str) -> str:
    """The blocking variant of ``source``, formatted by the pinned ruff."""
    want = pinned_ruff()
    have = _ruff("--version").split()[-1]
    if have != want:
        raise GenerateError(f"ruff {have} is installed, the generator is pinned to ruff {want}")
    out = source
    for pattern, replacement in _RULES:
        out = re.sub(pattern, replacement, out)
    return _ruff("format", "--stdin-filename", str(TARGET), "-", stdin=_HEADER + out)


def main(argv: list[str]) -> int:
    """Write (or with ``--check`` verify) ``client.py``."""
    try:
        expected = generate(SOURCE.read_text(encoding="utf-8"))
    except GenerateError as exc:
        print(f"unasync: {exc}", file=sys.stderr)
        return 2
    if "--check" in argv:
        current = TARGET.read_text(encoding="utf-8") if TARGET.exists() else ""
        if current != expected:
            print("client.py is stale: run python tools/unasync.py", file=sys.stderr)
            return 1
        return 0
    TARGET.write_text(expected, encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
