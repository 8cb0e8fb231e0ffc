"""What `opendnc lsv2` prints for a person: real destinations, readable nested values."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from typer.testing import CliRunner

from opendnc.cli.main import app
from opendnc.sim.tnc import TncHandle, start_tnc

runner = CliRunner()


@pytest.fixture(scope="module")
def itnc(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TncHandle]:
    with start_tnc("itnc530", root=tmp_path_factory.mktemp("itnc")) as handle:
        yield handle


def lsv2(handle: TncHandle, *args: str) -> str:
    result = runner.invoke(app, ["lsv2", "--port", str(handle.port), *args], env={"COLUMNS": "200"})
    assert result.exit_code == 0, result.output
    return result.stdout


def test_get_into_folder_names_each_file(itnc: TncHandle, tmp_path: Path) -> None:
    out = lsv2(itnc, "get", "TNC:/POCKET.H", "TNC:\\1001.I", str(tmp_path))
    assert f"get TNC:/POCKET.H -> {tmp_path / 'POCKET.H'} (" in out
    assert f"get TNC:\\1001.I -> {tmp_path / '1001.I'} (" in out
    assert (tmp_path / "POCKET.H").is_file()


def test_put_into_folder_names_each_file(itnc: TncHandle, tmp_path: Path) -> None:
    a, b = tmp_path / "A.H", tmp_path / "B.H"
    a.write_text("0 BEGIN PGM A MM\n1 END PGM A MM\n")
    b.write_text("0 BEGIN PGM B MM\n1 END PGM B MM\n")
    lsv2(itnc, "mkdir", "TNC:/job")
    out = lsv2(itnc, "put", str(a), str(b), "TNC:/job")
    assert f"put {a} -> TNC:/job/A.H (" in out
    assert f"put {b} -> TNC:/job/B.H (" in out


def test_info_shows_system_info_as_fields(itnc: TncHandle) -> None:
    out = lsv2(itnc, "info")
    assert "SystemInfo(" not in out
    assert "dnc_allowed=True" in out
