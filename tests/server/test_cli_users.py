"""`opendnc users create|password`: the people who log in to the dashboard."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from sqlalchemy.orm import Session, sessionmaker

from opendnc.server.access import auth
from opendnc.server.core.errors import Unauthorized
from opendnc.server.store.db import make_engine, make_sessions
from opendnc.server.store.models import Role
from tests.server.conftest import on


def _cli(*args: str, stdin: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "opendnc.cli.main", *args],
        input=stdin,
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )


@on("postgresql")
def test_create_a_user_then_change_the_password(tmp_path: Path, db_url: str) -> None:
    config = tmp_path / "shop.toml"
    config.write_text("")
    common = ("--config", str(config), "--db", db_url, "--password-stdin")
    made = _cli("users", "create", "ann", "--role", "approver", *common, stdin="first-pass-1\n")
    assert made.returncode == 0, made.stderr
    assert made.stdout.strip() == "user ann created (approver)"
    again = _cli("users", "create", "ann", "--role", "viewer", *common, stdin="first-pass-1\n")
    assert again.returncode == 1
    assert again.stderr.strip() == "error: user 'ann' exists already"
    short = _cli("users", "password", "ann", *common, stdin="short\n")
    assert short.returncode == 1
    assert "at least 8 characters" in short.stderr
    changed = _cli("users", "password", "ann", *common, stdin="second-pass-2\n")
    assert changed.returncode == 0, changed.stderr

    engine = make_engine(db_url)
    sessions: sessionmaker[Session] = make_sessions(engine)
    try:
        with sessions.begin() as session:
            assert auth.check_password(session, "ann", "second-pass-2").role is Role.APPROVER
            with pytest.raises(Unauthorized):
                auth.check_password(session, "ann", "first-pass-1")
    finally:
        engine.dispose()
