"""`opendnc lsv2 scope` as a new user reads it: names from `channels` usable in `record`."""

from __future__ import annotations

import json
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


def lsv2(handle: TncHandle, *args: str) -> tuple[int, str]:
    result = runner.invoke(app, ["lsv2", "--port", str(handle.port), *args])
    return result.exit_code, result.output


def test_channels_json_lists_signals_without_wire_padding(itnc: TncHandle) -> None:
    code, out = lsv2(itnc, "--json", "scope", "channels")
    assert code == 0
    channels = {ch["number"]: ch for ch in json.loads(out)}
    assert channels[0]["signals"] == ["X", "Y", "Z", "B", "C"]
    assert channels[6]["signals"] == ["M", "T", "C", "I", "O", "B", "W", "D"]


def test_record_accepts_signal_names_from_channels(itnc: TncHandle, tmp_path: Path) -> None:
    by_name, by_index = tmp_path / "name.csv", tmp_path / "index.csv"
    code, out = lsv2(itnc, "scope", "record", str(by_name), "-s", "0:x", "-s", "2:Z")
    assert code == 0, out
    code, out = lsv2(itnc, "scope", "record", str(by_index), "-s", "0:0", "-s", "2:2")
    assert code == 0, out
    header = by_name.read_text().splitlines()[0]
    assert header == by_index.read_text().splitlines()[0]
    assert header == "time_us,s actual X [mm],v actual Z [mm/min]"


def test_record_unknown_signal_name_lists_the_choices(itnc: TncHandle, tmp_path: Path) -> None:
    code, out = lsv2(itnc, "scope", "record", str(tmp_path / "s.csv"), "-s", "0:Q")
    assert code == 1
    assert "channel 0 (s actual) has no signal 'Q': use one of X Y Z B C" in out
    assert not (tmp_path / "s.csv").exists()
    code, out = lsv2(itnc, "scope", "record", str(tmp_path / "s.csv"), "-s", "0:1:y")
    assert code == 1
    assert "bad signal '0:1:y'" in out
