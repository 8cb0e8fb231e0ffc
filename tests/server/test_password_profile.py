"""Passwords are hashed at the shop's cost unless a test suite asks for argon2's cheapest
parameters (tests/conftest.py does); an unknown profile name is one clear error."""

from __future__ import annotations

import os
import subprocess
import sys

SHOW = (
    "from opendnc.server.access import auth; h = auth._hasher; "
    "print(h.time_cost, h.memory_cost, h.parallelism)"
)


def _run(profile: str | None) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if k != "OPENDNC_PASSWORD_PROFILE"}
    if profile is not None:
        env["OPENDNC_PASSWORD_PROFILE"] = profile
    return subprocess.run(
        [sys.executable, "-c", SHOW], env=env, capture_output=True, text=True, timeout=60
    )


def test_the_shop_gets_rfc_9106_low_memory_and_tests_may_ask_for_the_cheapest() -> None:
    assert _run(None).stdout.split() == ["3", "65536", "4"]  # passes, KiB, lanes
    assert _run("cheapest").stdout.split() == ["1", "8", "1"]


def test_an_unknown_profile_is_one_line_naming_the_known_ones() -> None:
    done = _run("fast")
    assert done.returncode != 0
    assert "OPENDNC_PASSWORD_PROFILE='fast' is not one of: rfc9106-low-memory, cheapest" in (
        done.stderr
    )
