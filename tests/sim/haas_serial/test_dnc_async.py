"""The asyncio drip-feed driver, with the virtual Haas on a pyserial ``socket://`` URL."""

from __future__ import annotations

import asyncio
import contextlib
import time
from pathlib import Path

from opendnc.haas.dnc import DncConfig, DncReport, stream_program_async
from opendnc.sim.haas import HaasConfig, SimHaasThread, SimOptions
from opendnc.sim.haas.dnc_link import DncLimits
from opendnc.sim.haas.serial_front import SerialFrontEnd, SerialOptions, parse_mode, start_serial

from .test_dnc_serial import write_program


def test_async_drip_feed_over_socket_url(tmp_path: Path) -> None:
    program = tmp_path / "p.nc"
    want = write_program(program, 3000, pad=100)
    # socket:// has no line rate: what the sender wrote before it saw the XOFF is bounded by
    # scheduling alone (the simulator shares this process's GIL), not by a UART. Overrun
    # detection is tested on paced lines; here only a sender that never stops may trip it.
    limits = DncLimits(buffer_blocks=16, overrun_blocks=1_000_000)
    options = SerialOptions(mode=parse_mode("dnc"), limits=limits)
    thread = SimHaasThread(HaasConfig(), tmp_path / "mem", SimOptions(mdc_port=None))

    async def main() -> tuple[DncReport, SerialFrontEnd]:
        done: asyncio.Future[DncReport] = asyncio.get_running_loop().create_future()
        fronts: list[SerialFrontEnd] = []
        hung_up = asyncio.Event()

        async def session(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
            try:
                # pyserial clears pending input when it opens the socket: wait for the DC1 that
                # the control sends once it is listening
                config = DncConfig(chunk=256, wait_for_xon=True)
                done.set_result(
                    await stream_program_async(
                        reader, writer, program, safe_mode=False, config=config
                    )
                )
            except Exception as exc:  # handed to the test by the future
                done.set_exception(exc)
            # TCP buffers hold much of the program: stay connected (and keep reading the
            # control's DC1/DC3, since closing with unread input resets the connection)
            # until the control has taken the closing %
            deadline = time.monotonic() + 30
            while not (fronts and fronts[0].messages) and time.monotonic() < deadline:
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(reader.read(4096), 0.05)
            writer.close()
            with contextlib.suppress(OSError):
                await writer.wait_closed()
            hung_up.set()

        server = await asyncio.start_server(session, "127.0.0.1", 0)
        port = server.sockets[0].getsockname()[1]
        loop = asyncio.get_running_loop()
        sim = await loop.run_in_executor(None, thread.start)

        async def attach() -> SerialFrontEnd:
            front = await start_serial(sim, f"socket://127.0.0.1:{port}", 115200, None, options)
            sim.add_front_end(front)
            return front

        front = await loop.run_in_executor(None, thread._submit, attach())
        fronts.append(front)
        report = await asyncio.wait_for(done, 60)
        await asyncio.wait_for(hung_up.wait(), 40)
        server.close()
        await server.wait_closed()
        return report, front

    try:
        report, front = asyncio.run(main())
        # the next (re-armed) DNC job then finds the socket closed: no run, so no alarm
        assert front.messages[0] == "RS232 DONE"
        assert report.bytes_sent == program.stat().st_size
        assert front.xoffs > 0  # back-pressure did happen
        control = thread.sim.control  # type: ignore[union-attr]
        assert thread.call(lambda: control.machine.get(101)) == want
        assert thread.call(lambda: control.runner.index) == 3002
    finally:
        thread.stop()
