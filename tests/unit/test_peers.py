"""Skips go through tests/peers.py, and under CI=true they are failures."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from tests import peers

TESTS = Path(__file__).resolve().parents[1]
REPO = TESTS.parent


def test_missing_peer_fails_under_ci(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(peers, "IN_CI", True)
    with pytest.raises(pytest.fail.Exception, match="CI=true"):
        peers.require_module("opendnc_no_such_module")
    with pytest.raises(pytest.fail.Exception, match="CI=true"):
        peers.require_command("opendnc-no-such-command")


def test_missing_peer_skips_on_a_developer_machine(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(peers, "IN_CI", False)
    with pytest.raises(pytest.skip.Exception, match="opendnc_no_such_module"):
        peers.require_module("opendnc_no_such_module")


def test_present_peers_are_returned() -> None:
    assert peers.require_module("json").dumps([]) == "[]"
    assert Path(peers.require_command("sh")).name == "sh"


def test_no_test_skips_around_peers_py() -> None:
    """Every skip is a peers.py call, so CI=true turns it into a failure."""
    direct = re.compile(r"pytest\.(skip|importorskip)\(|mark\.skip(if)?\b")
    offenders = [
        f"{path.relative_to(REPO)}:{number}"
        for path in sorted(TESTS.rglob("*.py"))
        if path.name not in {"peers.py", "test_peers.py"}
        for number, line in enumerate(path.read_text("utf-8").splitlines(), 1)
        if direct.search(line)
    ]
    assert not offenders


def test_ci_entry_point_sets_ci() -> None:
    script = (REPO / ".ci" / "run").read_text("utf-8")
    assert re.search(r"^export CI=true$", script, re.MULTILINE)
    assert script.index("export CI=true") < script.index("make test")
