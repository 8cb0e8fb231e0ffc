"""One supervised task per machine: connect, poll the status, listen, and run due jobs.

A task that loses its control closes the link, waits with exponential backoff (0.5 s up to
10 s, cut short by a job queued for it) and connects again; an error in one machine's task
never reaches another's. Between two status polls the task lets the runner
(:mod:`opendnc.server.jobs.runner`) claim and run the machine's due jobs on the same connector,
auto-receive (:mod:`opendnc.server.machines.autoreceive`) look at an out-tray folder, and, on a
control that sends by itself, listens for a punch that remote requests
(:mod:`opendnc.server.fleet.remote_request`) files or answers.

Which machines this process serves is decided at run time: :meth:`Fleet.serve` starts a
machine's task and :meth:`Fleet.release` stops it (closing its link), so a later "which
machines do I hold" decision (several servers on one database) only calls these two.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable

from opendnc.errors import DncError
from opendnc.server.config.shop import MachineConfig
from opendnc.server.core.components import cancel_and_wait
from opendnc.server.core.events import LeaseChanged
from opendnc.server.core.status import MachineStatus
from opendnc.server.fleet.remote_request import RemoteRequests
from opendnc.server.jobs.runner import JobRunner
from opendnc.server.kinds.connector import Connector
from opendnc.server.machines.autoreceive import AutoReceive
from opendnc.server.machines.state import Machines, MachineState
from opendnc.server.store.models import utcnow

__all__ = ["CLOSE_TIMEOUT", "ConnectorFactory", "Fleet"]

log = logging.getLogger(__name__)

ConnectorFactory = Callable[[MachineConfig], Connector]
CLOSE_TIMEOUT = 2.0  # seconds a link may take to close when its task stops
# The longest wait between two tries to reach a control that is away: a machine switched on
# in the morning is seen within this, and a hundred absent ones cost ten tries a second.
BACKOFF_MAX_S = 10.0
# a machine owed the rest of a fenced drip-feed: why its status is not read meanwhile
OWED = "not asked for its state: the rest of a drip-feed is its next input"


class Fleet:
    """The machines' tasks; a component."""

    name = "fleet"
    # what must run before a machine's first status: the parts that hand it work, and every
    # listener of its statuses (the outputs, the timeline; ``listeners`` adds optional ones)
    needs: tuple[str, ...] = (
        "machines",
        "runner",
        "remote-requests",
        "auto-receive",
        "dprnt",
        "outputs",
        "timeline",
    )

    def __init__(
        self,
        machines: Machines,
        runner: JobRunner,
        requests: RemoteRequests,
        autoreceive: AutoReceive,
        connector_factory: ConnectorFactory,
        *,
        serve_all: bool = True,
        listeners: tuple[str, ...] = (),
    ) -> None:
        self.needs = (*type(self).needs, *listeners)  # the alerts, where configured
        self.machines = machines
        self.serve_all = (
            serve_all  # False in a cluster: the leases decide (server/cluster/cluster.py)
        )
        self.runner = runner
        self.requests = requests
        self.autoreceive = autoreceive
        self.connector_factory = connector_factory
        self._tasks: dict[str, asyncio.Task[None]] = {}

    async def start(self) -> None:
        """Serve every configured machine (in a cluster, none until a lease is held)."""
        if not self.serve_all:
            return
        server = self.machines.config.server.name
        for name in self.machines.machines:
            # a single server holds every machine: the same word a cluster's gain is
            self.machines.bus.publish(LeaseChanged(name, server, True))
            self.serve(name)

    async def stop(self) -> None:
        """Stop every machine's task (each closes its link)."""
        tasks = list(self._tasks.values())
        self._tasks.clear()
        await cancel_and_wait(*tasks)

    @property
    def served(self) -> frozenset[str]:
        """The machines this process serves now."""
        return frozenset(self._tasks)

    def serve(self, name: str) -> None:
        """Start serving machine ``name`` (nothing if it is served already)."""
        if name in self._tasks:
            return
        state = self.machines.machines[name]
        self._tasks[name] = asyncio.create_task(self._supervise(state), name=f"machine-{name}")
        state.wake.set()  # a first look at its queue

    async def release(self, name: str) -> None:
        """Stop serving machine ``name``: its task ends and its link closes."""
        task = self._tasks.pop(name, None)
        if task is not None:
            await cancel_and_wait(task)
        state = self.machines.get(name)
        if state is not None:
            state.online = False
            # A job cut off here is no longer run by this process: the runner's sweep hands
            # it back (a load to the queue, a drip-feed interrupted) unless its end is
            # already on its way to the database.
            state.job_id = None
            state.job_progress = (0, None)
            self.machines.publish(state)

    async def _supervise(self, state: MachineState) -> None:
        # Made inside the loop: a kind's connector module is imported when the first machine
        # of the kind is served, and one that cannot be (a library of an extra missing) must
        # show on the machine as its error, not end its task without a word.
        connector: Connector | None = None
        backoff = 0.5
        while True:
            try:
                if connector is None:
                    connector = self.connector_factory(state.config)
                await connector.connect()
                state.online = True
                backoff = 0.5
                state.wake.set()  # what was queued while it was away runs at once
                await self._serve(state, connector)
            except asyncio.CancelledError:
                if connector is not None:
                    await _close(connector)
                raise
            except Exception as exc:
                if not isinstance(exc, DncError):
                    log.exception("%s: unexpected error", state.config.name)
                state.online = False
                state.last_error = str(exc) or type(exc).__name__
                state.last_error_at = utcnow()
                state.link_errors += 1
                state.errands.fail_all(f"{state.config.name} is offline: {state.last_error}")
                state.set_status(
                    MachineStatus(at=utcnow(), available=False, message=state.last_error)
                )
                self.machines.publish(state)
                if connector is not None:
                    await _close(connector)
                # a job queued meanwhile cuts the wait short: the person who queued it
                # expects a try now, not at the end of a long backoff
                await _wait(state.wake, backoff)
                state.wake.clear()
                backoff = min(backoff * 2, BACKOFF_MAX_S)

    async def _serve(self, state: MachineState, connector: Connector) -> None:
        loop = asyncio.get_running_loop()
        while True:
            if state.awaiting_position is not None:
                # taken over mid-feed: the control may still wait in DNC mode for the rest,
                # so nothing is said to it (no poll, no listening) until the old server's
                # position is in or the wait is over (docs/server.md#a-fenced-drip-feed)
                await self.runner.await_position(state)
            if state.wake.is_set():
                state.wake.clear()
                await self.runner.run_due(state, connector)
            if state.feed_owed and await self.runner.owes_feed(state):
                # the rest of a fenced drip-feed is this control's next input, and nothing
                # else may come before it (docs/server.md#a-fenced-drip-feed): the queue
                # again in a moment, no errand, no poll, no listening meanwhile; its status
                # (API, outputs) says why it is not read, not the last poll's word as if live
                if state.status is None or state.status.message != OWED:
                    state.set_status(MachineStatus(at=utcnow(), available=True, message=OWED))
                    self.machines.publish(state)
                await _wait(state.wake, state.config.poll_interval)
                state.wake.set()
                continue
            await state.errands.run(connector)  # the file browser's reads, between jobs
            asked = loop.time()
            state.set_status(await connector.status())
            self.machines.publish(state)
            await self.autoreceive.look(state, connector)
            if connector.listens:
                # Waiting for a punch or a remote request is what a serial port does between
                # jobs; a queued job waits at most one listening window.
                reception = await connector.listen(state.config.poll_interval)
                if reception is not None:
                    await self.requests.received(state, reception)
                else:
                    # A port that reads nothing at once (an adapter pulled out, a cable's far
                    # end gone) must not make this loop spin: a quarter of the interval
                    # passes between two listens, as between two polls below.
                    left = state.config.poll_interval / 4 - (loop.time() - asked)
                    if left > 0:
                        await _wait(state.wake, left)
            else:
                # Polls start every poll_interval, however long the last one took to answer:
                # a status is never older than the interval plus one answer's time (waiting
                # the whole interval after each answer would add the answer's time to every
                # status's age, and under load that is a large part of it).
                # A quarter of the interval stays free whatever the answer took: on a
                # machine short of CPU, polls back to back would only take more of it.
                interval = state.config.poll_interval
                left = interval - (loop.time() - asked)
                await _wait(state.wake, max(interval / 4, left))


async def _wait(event: asyncio.Event, seconds: float) -> None:
    """Wait until ``event`` is set or ``seconds`` pass (a cancel always gets through:
    ``asyncio.timeout`` does not swallow one the way ``wait_for`` can)."""
    with contextlib.suppress(TimeoutError):
        async with asyncio.timeout(seconds):
            await event.wait()


async def _close(connector: Connector) -> None:
    """Close a link, giving up after :data:`CLOSE_TIMEOUT` (a control that stopped answering
    must not hold up a stop)."""
    try:
        async with asyncio.timeout(CLOSE_TIMEOUT):
            await connector.close()
    except TimeoutError:
        log.warning("a link did not close within %.0f s; left to the system", CLOSE_TIMEOUT)
    except DncError:
        pass
