"""Generated sources are current, and their generator stays out of the installed package."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import pytest

import opendnc

ROOT = Path(__file__).resolve().parents[2]
TOOL = ROOT / "tools" / "unasync.py"


def _load_tool() -> ModuleType:
    spec = importlib.util.spec_from_file_location("unasync_tool", TOOL)
    assert spec is not None
    assert spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_blocking_lsv2_client_is_generated_from_the_async_one() -> None:
    done = subprocess.run(
        [sys.executable, str(TOOL), "--check"], capture_output=True, text=True, check=False
    )
    assert done.returncode == 0, done.stderr or "run: python tools/unasync.py"


def test_check_reports_a_stale_client(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    tool = _load_tool()
    stale = tmp_path / "client.py"
    stale.write_text(tool.TARGET.read_text(encoding="utf-8") + "# edited by hand\n")
    monkeypatch.setattr(tool, "TARGET", stale)
    assert tool.main(["--check"]) == 1


def test_generator_renames_the_async_api() -> None:
    out = _load_tool().generate("async def f(c: AsyncClient) -> None:\n    await c.x()\n")
    assert "def f(c: Client) -> None:\n    c.x()\n" in out
    assert "async" not in out.split("\n", 1)[1]
    assert "await" not in out


def test_generator_is_not_part_of_the_package() -> None:
    package = Path(opendnc.__file__).parent
    assert not [p for p in package.rglob("*.py") if "unasync" in p.name]
