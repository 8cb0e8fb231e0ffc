"""Put the virtual Haas together: control model, MDC server, DPRNT outputs, block executor.

:class:`SimHaas` runs on an asyncio loop; :class:`SimHaasThread` runs one on a background
thread for tests and embedding, with :meth:`SimHaasThread.call` to reach the model safely.
A serial front-end is added by giving it ``sim.control`` (and attaching its DPRNT output for
:attr:`DprntDestination.SERIAL`) before or after :meth:`SimHaas.start`.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import threading
from collections.abc import Callable, Coroutine
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol, TypeVar

from opendnc.sim.haas.control import DprntDestination, HaasConfig, HaasControl
from opendnc.sim.haas.dprnt_out import FileDprntOutput, TcpDprntOutput
from opendnc.sim.haas.mdc_server import MdcServer, Trace
from opendnc.sim.haas.runner import StepResult
from opendnc.sim.haas.store import ProgramStore

T = TypeVar("T")


class FrontEnd(Protocol):
    """Anything attached to the control that must be closed with the simulator."""

    async def close(self) -> None:
        """Release ports and tasks."""
        ...


@dataclass
class SimOptions:
    """Network-side options of the simulator (identity and behaviour are in HaasConfig)."""

    host: str = "127.0.0.1"
    mdc_port: int | None = 5051  # None: no MDC server
    dprnt_tcp_port: int | None = None  # start the DPRNT TCP output on this port (0 = any)
    dprnt_file: Path | None = None
    block_rate: float = 0.0  # blocks per second; 0 = as fast as possible
    trace: Trace | None = None


class SimHaas:
    """The running simulator on the current asyncio loop."""

    def __init__(self, config: HaasConfig, root: Path, options: SimOptions) -> None:
        self.options = options
        self.control = HaasControl(config, ProgramStore(root))
        self.mdc: MdcServer | None = None
        self.dprnt_tcp: TcpDprntOutput | None = None
        self.dprnt_file: FileDprntOutput | None = None
        self.front_ends: list[FrontEnd] = []
        self._wake = asyncio.Event()
        self._executor: asyncio.Task[None] | None = None

    def add_front_end(self, front_end: FrontEnd) -> None:
        """Keep ``front_end`` to be closed by :meth:`close`."""
        self.front_ends.append(front_end)

    async def start(self) -> None:
        """Open the configured ports and start executing programs."""
        opts, control = self.options, self.control
        if opts.mdc_port is not None:
            self.mdc = MdcServer(control, opts.host, opts.mdc_port, trace=opts.trace)
            control.machine.settings[143] = await self.mdc.start()
        if opts.dprnt_tcp_port is not None:
            self.dprnt_tcp = TcpDprntOutput(opts.host, opts.dprnt_tcp_port)
            control.machine.settings[263] = await self.dprnt_tcp.start()
            control.attach_dprnt(DprntDestination.TCP, self.dprnt_tcp)
        if opts.dprnt_file is not None:
            self.dprnt_file = FileDprntOutput(opts.dprnt_file)
            control.machine.settings[262] = str(opts.dprnt_file)
            control.attach_dprnt(DprntDestination.FILE, self.dprnt_file)
        loop = asyncio.get_running_loop()

        def wake() -> None:
            loop.call_soon_threadsafe(self._wake.set)

        control.wake = wake
        wake()  # a program may have been started before the executor existed
        self._executor = asyncio.create_task(self._execute())

    async def close(self) -> None:
        """Stop executing and close every port."""
        if self._executor is not None:
            self._executor.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._executor
        for front_end in self.front_ends:
            await front_end.close()
        if self.mdc is not None:
            await self.mdc.close()
        if self.dprnt_tcp is not None:
            await self.dprnt_tcp.close()

    async def _execute(self) -> None:
        # One block per tick at --block-rate (read at every block: a test may slow the control
        # down mid-run); a DNC source that has no next block yet parks the executor until a
        # front-end appends lines (it calls control.wake()).
        while True:
            await self._wake.wait()
            self._wake.clear()
            while (result := self.control.step()) is not None:
                if result is StepResult.WAITING:
                    break
                rate = self.options.block_rate
                await asyncio.sleep(1.0 / rate if rate > 0 else 0)


class SimHaasThread:
    """A :class:`SimHaas` on its own event loop thread (for tests and the demo)."""

    def __init__(self, config: HaasConfig, root: Path, options: SimOptions) -> None:
        self._config, self._root, self._options = config, root, options
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, daemon=True)
        self.sim: SimHaas | None = None

    def __enter__(self) -> SimHaasThread:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def start(self) -> SimHaas:
        """Start the loop thread and the simulator on it."""
        self._thread.start()

        async def build() -> SimHaas:
            sim = SimHaas(self._config, self._root, self._options)
            await sim.start()
            return sim

        self.sim = self._submit(build())
        return self.sim

    def stop(self) -> None:
        """Close the simulator and end the loop thread."""
        if self.sim is not None:
            self._submit(self.sim.close())
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(5)
        self._loop.close()

    def call(self, func: Callable[[], T], timeout: float = 5.0) -> T:
        """Run ``func`` on the simulator's loop thread and return its result."""

        async def run() -> T:
            return func()

        return self._submit(run(), timeout)

    def _submit(self, coro: Coroutine[Any, Any, T], timeout: float = 5.0) -> T:
        future: concurrent.futures.Future[T] = asyncio.run_coroutine_threadsafe(coro, self._loop)
        return future.result(timeout)
