"""`sim fleet --fanuc N`: virtual Fanucs on cables of their own, served by the server's
``serial`` kind (tests/server/test_serial_kind.py runs them with the server)."""

from __future__ import annotations

import asyncio
from pathlib import Path

from opendnc.sim.fleet import server_config, start_fleet
from opendnc.tape.profiles import get_profile
from opendnc.tape.serial_io import send_program
from tests.sim.tape.conftest import wait_for


def test_a_fleet_fanuc_reads_a_program(tmp_path: Path) -> None:
    program = tmp_path / "O0010.nc"
    program.write_text("%\nO0010 (FLEET)\nG00 X0.\nM30\n%\n")

    machine_serial = ""

    async def main() -> tuple[str, list[str]]:
        nonlocal machine_serial
        fleet = await start_fleet(tmp_path / "fleet", tnc=0, haas=0, fanuc=1)
        try:
            (machine,) = fleet.machines
            machine_serial = machine.serial
            profile = get_profile("fanuc-0i").with_changes(baud=machine.baud)
            await asyncio.to_thread(send_program, machine.serial, program, profile)
            sim = fleet.fanucs["fanuc-1"]
            await asyncio.to_thread(wait_for, lambda: sim.programs() == ["O0010.nc"])
            return server_config(fleet), sim.programs()
        finally:
            await fleet.close()

    config, programs = asyncio.run(main())
    assert programs == ["O0010.nc"]
    assert 'kind = "serial"' in config
    assert f'serial = "{machine_serial}"' in config
