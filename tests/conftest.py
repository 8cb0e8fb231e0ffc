"""Shared fixtures, and the order the suite runs in."""

from __future__ import annotations

import pytest

# The files whose tests take longest (tens of seconds each: `pytest --durations=80`), longest
# first. pytest-xdist hands the first tests of the collection out round-robin as the run
# starts, so these begin on every worker at once instead of one of them keeping a worker busy
# alone at the end of the run. Only the order changes: each file keeps its own order (its
# module fixtures are set up as often as before), and every other file follows as collected.
# The list need not be exact; a file that grew slow only makes the run end later.
LONGEST_FIRST = (
    "tests/interop/test_xmodem_pypi.py",
    "tests/interop/test_xmodem_lrzsz.py",
    "tests/sim/haas_serial/test_dnc_large.py",
    "tests/bench/test_soak_serial_lsv2.py",
    "tests/sim/test_heidenhain_blockwise_cable.py",
    "tests/cli/test_readme.py",
    "tests/server/test_from_the_control.py",
    "tests/web/test_machine_page.py",
    "tests/server/test_serial_mdc_status.py",
    "tests/server/test_end_to_end.py",
    "tests/server/test_leases.py",
    "tests/web/test_dashboard.py",
    "tests/server/test_sim_fleet_cli.py",
    "tests/server/test_serial_profile.py",
    "tests/sim/test_xmodem_text_check.py",
    "tests/server/test_serve.py",
    "tests/sim/test_lsv2_serial_adaptive.py",
    "tests/sim/test_lsv2_serial_faults.py",
    "tests/unit/test_portable.py",
    "tests/server/test_limits.py",
    "tests/sim/tnc/test_properties.py",
    "tests/server/test_stop.py",
    "tests/server/test_tnc_autoreceive.py",
    "tests/sim/haas_serial/test_cli_serial.py",
    "tests/bench/test_soak_smoke.py",
)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Put the longest files first (see :data:`LONGEST_FIRST`); a stable sort keeps the rest
    of the order."""
    rank = {path: i for i, path in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.nodeid.split("::", 1)[0], len(rank)))
