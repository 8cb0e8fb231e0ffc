"""The asyncio drivers share the engine: send and punch back with the virtual Fanuc on a
TCP link (as behind a serial device server), loopback only."""

from __future__ import annotations

import asyncio
from pathlib import Path

from opendnc.sim.fanuc import FanucOptions, VirtualFanuc
from opendnc.tape.aio import receive_record_async, send_program_async
from opendnc.tape.profiles import get_profile
from opendnc.tape.serial_io import expected_text

TEXT = "%\nO0008 (ASYNC)\nG21\nG00 X1. Y2.\nM30\n%\n"


def test_async_send_and_punch_back(tmp_path: Path) -> None:
    path = tmp_path / "O0008.nc"
    path.write_text(TEXT)
    profile = get_profile("fanuc-0i")

    async def main() -> str:
        connected: asyncio.Queue[tuple[asyncio.StreamReader, asyncio.StreamWriter]]
        connected = asyncio.Queue()

        async def accept(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
            await connected.put((reader, writer))

        server = await asyncio.start_server(accept, "127.0.0.1", 0)
        port = server.sockets[0].getsockname()[1]
        sim = VirtualFanuc(
            f"tcp://127.0.0.1:{port}",
            tmp_path / "mem",
            profile=profile,
            options=FanucOptions(punch_back=True),
        )
        await asyncio.to_thread(sim.start)
        try:
            reader, writer = await asyncio.wait_for(connected.get(), 5)
            kept = bytearray()
            await send_program_async(reader, writer, path, profile, keep=kept, xoff_timeout=10)
            record = await receive_record_async(reader, profile, timeout=10, already=bytes(kept))
            writer.close()
            return record.text
        finally:
            await asyncio.to_thread(sim.close)
            server.close()
            await server.wait_closed()

    assert asyncio.run(main()) == TEXT == expected_text(path, profile)
