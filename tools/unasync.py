"""Generate the blocking client (``client.py``) from the asyncio client (``aio.py``).

Both facades are thin layers over the same operations; writing one by hand and deriving the
other keeps them from drifting apart. Run ``python -m opendnc.lsv2._unasync`` after editing
``aio.py``; ``--check`` exits non-zero when ``client.py`` is stale (a unit test does this).
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).parent
SOURCE = HERE / "aio.py"
TARGET = HERE / "client.py"

_HEADER = "# Generated from aio.py by opendnc.lsv2._unasync; edit aio.py, then regenerate.\n"

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


def generate(source: str) -> str:
    """The blocking variant of ``source``, formatted by ruff (lines get shorter)."""
    out = source
    for pattern, replacement in _RULES:
        out = re.sub(pattern, replacement, out)
    out = _HEADER + out
    done = subprocess.run(
        [sys.executable, "-m", "ruff", "format", "--stdin-filename", str(TARGET), "-"],
        input=out,
        capture_output=True,
        text=True,
        check=False,
        cwd=HERE,
    )
    if done.returncode != 0:
        raise RuntimeError(f"ruff format failed: {done.stderr.strip()}")
    return done.stdout


def main(argv: list[str]) -> int:
    """Write (or with ``--check`` verify) ``client.py``."""
    expected = generate(SOURCE.read_text(encoding="utf-8"))
    if "--check" in argv:
        current = TARGET.read_text(encoding="utf-8") if TARGET.exists() else ""
        if current != expected:
            print("client.py is stale: run python -m opendnc.lsv2._unasync", file=sys.stderr)
            return 1
        return 0
    TARGET.write_text(expected, encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
