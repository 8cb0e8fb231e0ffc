"""Shared fixtures, and the order the suite runs in."""

from __future__ import annotations

import gc
import os
from collections.abc import Generator
from typing import Any

import pytest

# argon2's cheapest parameters for the passwords the tests make and check, in this process
# and in the servers and commands it starts (they inherit the environment): a third of a CPU
# second each at the shop's cost, hundreds of them in a run (opendnc.server.access.auth).
os.environ.setdefault("OPENDNC_PASSWORD_PROFILE", "cheapest")

# The files whose longest test takes longest (10 s and more on a busy machine, measured with
# `pytest --durations=0`), longest first. pytest-xdist hands the first tests of the collection
# out round-robin as the run starts, so these begin on every worker at once instead of one of
# them keeping a worker busy alone at the end of the run. Only the order changes: each file
# keeps its own order (its module fixtures are set up as often as before), and every other
# file follows as collected. The list need not be exact; a file that grew slow only makes the
# run end later.
LONGEST_FIRST = (
    "tests/cli/test_readme.py",
    "tests/bench/test_soak_smoke.py",
    "tests/server/test_end_to_end.py",
    "tests/server/test_db_silence.py",
    "tests/interop/test_xmodem_pypi.py",
    "tests/server/test_cluster.py",
    "tests/server/test_from_the_control.py",
    "tests/web/test_program_preview.py",
    "tests/server/test_limits.py",
    "tests/sim/haas_serial/test_cli_serial.py",
    "tests/web/test_utilization_pages.py",
    "tests/bench/test_soak_serial_lsv2.py",
    "tests/web/test_workbench.py",
    "tests/server/test_stop.py",
    "tests/sim/surface/test_report_page.py",
    "tests/web/test_program_preview_http.py",
    "tests/web/test_dashboard.py",
    "tests/sim/haas_serial/test_dnc_large.py",
    "tests/server/test_api_contract.py",
    "tests/web/test_machine_page.py",
    "tests/sim/test_lsv2_serial_adaptive.py",
    "tests/server/test_request_load.py",
    "tests/server/test_serial_mdc_status.py",
    "tests/server/test_utilization_days.py",
    "tests/sim/test_heidenhain_blockwise_cable.py",
    "tests/server/test_utilization_db.py",
    "tests/web/test_library_page.py",
    "tests/server/test_dprnt_capture.py",
    "tests/server/test_crash_gap.py",
    "tests/server/test_cli_users.py",
    "tests/server/test_tnc_autoreceive.py",
    "tests/sim/test_lsv2_serial_faults.py",
    "tests/web/test_sessions.py",
    "tests/sim/haas_serial/test_punch_back_verify.py",
    "tests/server/test_netshare.py",
    "tests/web/test_card_states.py",
    "tests/web/test_netshare_page.py",
    "tests/cli/test_demo.py",
    "tests/server/test_serial_profile.py",
    "tests/server/test_sparkplug_cluster.py",
    "tests/server/test_runner_endings.py",
    "tests/server/test_mqtt.py",
    "tests/interop/test_xmodem_lrzsz.py",
    "tests/sim/test_xmodem_text_check.py",
    "tests/server/test_policy_matrix.py",
    "tests/property/test_backplot.py",
    "tests/cli/test_cli_messages.py",
    "tests/web/test_floor.py",
    "tests/server/test_mtconnect.py",
    "tests/server/test_sparkplug.py",
    "tests/server/test_serve.py",
    "tests/web/test_utilization_api.py",
    "tests/server/test_leases.py",
    "tests/sim/test_lsv2_serial_cable.py",
)


@pytest.hookimpl(wrapper=True)
def pytest_collection(session: pytest.Session) -> Generator[None, object, object]:
    """Collect with the cyclic garbage collector paused, then freeze what collection made.

    Every worker imports every test module and what they import (the server, the protocol
    stacks): objects that live as long as the worker. Paused, the collector does not walk them
    while they are made; frozen, its later passes during the tests do not walk them either
    (measured: a third of the collector's time in a worker's tests, and half a CPU second of
    each worker's collection)."""
    gc.disable()
    try:
        return (yield)
    finally:
        gc.freeze()
        gc.enable()


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Put the longest files first (see :data:`LONGEST_FIRST`); a stable sort keeps the rest
    of the order."""
    rank = {path: i for i, path in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.nodeid.split("::", 1)[0], len(rank)))


# Files whose module fixture is dear (a server, a fleet of virtual controls, Chromium, Samba,
# a soak run): each runs on one worker, so its fixture is set up once. Spread over the six
# workers they were set up up to six times each, and a late one kept the run going alone at
# its end (seen: the dashboard's server, fleet and browser set up in the run's last minute).
ONE_WORKER = frozenset(
    {
        "tests/bench/test_soak_smoke.py",
        "tests/interop/test_haas_share_samba.py",
        "tests/server/test_api_contract.py",
        "tests/server/test_api_fixes.py",
        "tests/server/test_library_search.py",
        "tests/server/test_policy_matrix.py",
        "tests/server/test_program_checks.py",
        "tests/sim/test_heidenhain_blockwise_cable.py",
        "tests/sim/test_lsv2_serial_cable.py",
        "tests/web/test_dashboard.py",
        "tests/web/test_editor.py",
        "tests/web/test_floor.py",
        "tests/web/test_floor_goals.py",
        "tests/web/test_library_page.py",
        "tests/web/test_machine_page.py",
        "tests/web/test_netshare_page.py",
        "tests/web/test_program_preview.py",
        "tests/web/test_program_preview_http.py",
        "tests/web/test_utilization_api.py",
        "tests/web/test_utilization_pages.py",
        "tests/web/test_workbench.py",
    }
)


def pytest_xdist_make_scheduler(config: pytest.Config, log: Any) -> Any:
    """With ``-n`` (``--dist load``): every test is a unit of its own, but each of
    :data:`ONE_WORKER`'s files is one unit. (pytest-xdist's ``loadgroup`` does this with a
    mark, but it renames the test ids to do it, which pytest 9.2 no longer lets it do.) The
    files go out first, the largest first, then every other test in the collection's order."""
    if config.getvalue("dist") != "load":
        return None
    from xdist.scheduler import LoadScopeScheduling

    class OneWorkerFiles(LoadScopeScheduling):  # type: ignore[misc]
        def _split_scope(self, nodeid: str) -> str:
            path = nodeid.split("::", 1)[0]
            return path if path in ONE_WORKER else nodeid

    return OneWorkerFiles(config, log)
