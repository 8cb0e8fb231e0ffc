"""Finding third-party test peers: skipped on a developer machine, a failure under CI=true."""

from __future__ import annotations

import importlib
import os
import shutil
from pathlib import Path
from types import ModuleType

import pytest

IN_CI = os.environ.get("CI", "").lower() in {"1", "true", "yes"}


def missing_peer(what: str) -> None:
    """Skip (locally) or fail (in CI) because the peer ``what`` is not installed."""
    message = f"test peer not available: {what}"
    if IN_CI:
        pytest.fail(message + " (CI=true: a missing peer is a failure)")
    pytest.skip(message)


def require_command(name: str) -> str:
    """Return the path of command ``name`` or skip/fail."""
    path = shutil.which(name)
    if path is None:
        missing_peer(f"command {name!r}")
        raise AssertionError("unreachable")
    return path


def require_module(name: str) -> ModuleType:
    """Import and return module ``name`` or skip/fail."""
    try:
        return importlib.import_module(name)
    except ImportError:
        missing_peer(f"python module {name!r}")
        raise AssertionError("unreachable") from None


REPO = Path(__file__).resolve().parent.parent


def require_reference(relative: str) -> Path:
    """Return the file ``shared/reference/RELATIVE`` beside the repository or skip/fail.

    CI has ``shared/`` beside the clone; a developer's work tree may sit deeper (a worktree
    folder), so the folders above the repository are searched upwards. The reference data stays
    outside the repository: its README asks that it not be copied into the project.
    """
    for folder in (REPO, *REPO.parents):
        path = folder / "shared" / "reference" / relative
        if path.is_file():
            return path
    expected = REPO.parent / "shared" / "reference" / relative
    missing_peer(
        f"reference file shared/reference/{relative}: expected at {expected} (a shared/ "
        f"folder beside the clone, as CI lays it out) or in a folder above {REPO}"
    )
    raise AssertionError("unreachable")
