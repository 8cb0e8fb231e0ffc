"""Helpers for the serial-MDC, net share and DPRNT server tests: a server started against a
fleet whose serial Haas answers MDC. The rest is the server tests' shared harness."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from opendnc.sim.fleet import server_config
from tests.server.harness import (
    Procs,
    auth,
    create_key,
    free_port,
    httpx,
    listening,
    serve,
    start_server,
    wait_for,
)
from tests.server.test_from_the_control import (
    STORED,
    FleetThread,
    interrupt_dripfeed,
    slow_serial_haas,
)

__all__ = [
    "PRINTS",
    "STORED",
    "FleetThread",
    "Procs",
    "auth",
    "create_key",
    "free_port",
    "httpx",
    "interrupt_dripfeed",
    "listening",
    "serve",
    "serve_fleet",
    "slow_serial_haas",
    "wait_for",
]

# A Haas program that prints three DPRNT lines, PASS 0..2 with X doubling from 1.5.
PRINTS = """%
O00500 (PRINT THREE PASSES)
#100 = 0
#101 = 1.5
WHILE [#100 LT 3] DO1
DPRNT[PASS*#100[20]*X#101[24]]
#100 = #100 + 1
#101 = #101 * 2
END1
M30
%
"""


def serve_fleet(
    tmp_path: Path,
    fleet: FleetThread,
    procs: Procs,
    db_url: str,
    *,
    machine_keys: str = "",
    extra: str = "",
) -> tuple[Any, str]:
    """Start ``opendnc serve`` for the fleet's machines (serial Haas with ``mdc = true`` and
    ``machine_keys``; ``extra`` TOML appended); return an HTTP client and an admin key."""
    config = tmp_path / "shop.toml"
    text = server_config(
        fleet.fleet, poll_interval=0.5, library=tmp_path / "lib", mdc=True, check="warn"
    )
    text = text.replace("mdc = true\n", "mdc = true\n" + machine_keys)
    config.write_text(text + "\n[requests]\ndelay = 0.5\n" + extra)
    key = create_key(config, db_url)
    return start_server(procs, config, db_url), key
