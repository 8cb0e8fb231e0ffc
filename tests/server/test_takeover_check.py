"""What a server that took a machine over asks the control before sending a load again
(docs/server.md#jobs-in-a-cluster): a virtual TNC over LSV2 and a Haas NGC's net share folder, each
holding the program, another program under the name, or nothing."""

from __future__ import annotations

import asyncio
from pathlib import Path

from opendnc.server.jobs.executors import held_at_control
from opendnc.server.kinds.haas_ngc import HaasNgcMachine
from opendnc.server.kinds.haas_ngc.connector import HaasNgcConnector
from opendnc.server.kinds.lsv2 import Lsv2Machine
from opendnc.server.kinds.lsv2.connector import Lsv2Connector
from opendnc.sim.tnc.server import serve_tnc
from tests.server.cluster_support import program

PROGRAM = program(1, 3000)  # CR LF lines: sent in LSV2's ASCII mode


def test_a_tnc_is_asked_for_the_file_and_its_bytes(tmp_path: Path) -> None:
    async def run() -> list[bool | None]:
        tnc = await serve_tnc("tnc640", tmp_path / "tnc", "127.0.0.1", 0)
        connector = Lsv2Connector(Lsv2Machine(name="tnc-1", host="127.0.0.1", port=tnc.port))
        try:
            await connector.connect()
            answers = [await held_at_control(connector, "P01.H", PROGRAM)]  # folder: none yet
            await connector.send("P01.H", PROGRAM, lambda _done, _total: None)
            answers.append(await held_at_control(connector, "P01.H", PROGRAM))
            # the same name, other bytes (one digit), and another name
            other = PROGRAM.replace(b"X+1.", b"X+2.", 1)
            answers.append(await held_at_control(connector, "P01.H", other))
            answers.append(await held_at_control(connector, "P02.H", PROGRAM))
            # a file put anywhere on the drive (the file browser's): the same question by path
            path = "TNC:/nc_prog/Q1.H"
            answers.append(await connector.holds_file(path, PROGRAM))
            await connector.put_file(path, PROGRAM, lambda _done, _total: None)
            answers.append(await connector.holds_file(path, PROGRAM))
            answers.append(await connector.holds_file(path, other))
            return answers
        finally:
            await connector.close()
            await tnc.close()

    assert asyncio.run(run()) == [False, True, False, False, False, True, False]


def test_a_haas_share_is_asked_for_the_file_and_its_hash(tmp_path: Path) -> None:
    share = tmp_path / "share"
    share.mkdir()
    machine = HaasNgcMachine(name="haas-1", host="127.0.0.1", share=str(share))
    connector = HaasNgcConnector(machine)
    data = b"%\nO01000 (PART)\nG00 X0 Y0\nM30\n%\n"

    def ask(name: str, expected: bytes) -> bool | None:
        return asyncio.run(held_at_control(connector, name, expected))

    assert ask("O01000.nc", data) is False  # not there
    (share / "O01000.nc").write_bytes(data)
    assert ask("O01000.nc", data) is True
    assert ask("O01000.nc", data.replace(b"X0", b"X1")) is False  # same size, other bytes
    assert ask("O01000.nc", data + b"\n") is False  # another size
