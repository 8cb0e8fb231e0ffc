"""This server's part in a cluster: several servers on one PostgreSQL database.

:class:`Cluster` is a component (PostgreSQL only; SQLite serves one server). Every
``lease/4`` seconds it renews this server's heartbeat and machine leases
(:class:`~opendnc.server.machines.leases.Leases`), then acts on what changed:

- a machine gained: the jobs its previous server left running there are ended once
  (:meth:`JobRunner.take_over`: a load queued again, a drip-feed interrupted at its last
  recorded line), a :class:`~opendnc.server.core.events.LeaseChanged` is published, and the
  machine's task starts (:meth:`Fleet.serve`);
- a machine lost (handed over at a safe point, or taken after this server could not renew
  in time): its task stops (:meth:`Fleet.release`) and a ``LeaseChanged`` says so;
- the shop-wide duties (the library watcher, the net share) run on the one server holding
  the :data:`~opendnc.server.machines.leases.LIBRARY` lease.

If the database cannot be reached, or goes silent, this server stops driving its machines
before its leases could expire (``margin`` earlier), so two servers never drive one machine:
the renewal is awaited against that deadline on the process's monotonic clock, never longer,
and the runner asks :meth:`Cluster.epoch` before each block it writes
(docs/server.md#a-silent-database). It listens for the other
servers' notices (:mod:`opendnc.server.store.notify`): a queued or moved job wakes its machine at
once, a cancel reaches the job running here at once, and another server's new statuses are read
at once (``on_status``, :mod:`opendnc.server.fleet.shared_status`). docs/server.md#several-servers.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

from opendnc.server.core.components import DutyFlag, cancel_and_wait
from opendnc.server.core.events import LeaseChanged, ProgramChanged
from opendnc.server.fleet.shared_status import ORPHANED
from opendnc.server.fleet.tasks import Fleet
from opendnc.server.jobs.runner import JobRunner, database_down
from opendnc.server.machines.leases import LIBRARY, ClusterView, Holding, Leases, cluster_view
from opendnc.server.machines.state import Machines
from opendnc.server.outputs.items import SERVER_STOPPED
from opendnc.server.store.health import reason
from opendnc.server.store.notify import Listener, Notice, Topic

__all__ = ["FENCE_MARGIN_MIN", "Cluster"]

log = logging.getLogger(__name__)

# The least time before its leases could expire at which a server stops driving its machines:
# a drip-feed's next block boundary and the links' closing must fit in it.
FENCE_MARGIN_MIN = 1.0


class Cluster:
    """Holds this server's leases and serves exactly the machines it holds (a component)."""

    name = "cluster"
    needs = ("machines", "database", "runner", "fleet", "shared-status")

    def __init__(
        self,
        leases: Leases,
        machines: Machines,
        runner: JobRunner,
        fleet: Fleet,
        *,
        database_url: str,
        duty: DutyFlag | None = None,
        on_status: Callable[[str], None] = lambda _server: None,
    ) -> None:
        self.leases = leases
        self.machines = machines
        self.runner = runner
        self.fleet = fleet
        self.database_url = database_url
        # the shop-wide duties' flag: raised while this server holds their lease (the core
        # starts and stops the duties themselves)
        self.duty = duty if duty is not None else DutyFlag(held=False)
        self.on_status = on_status  # a server wrote statuses ("" after a reconnect: maybe)
        ttl = leases.ttl.total_seconds()
        self.renew_every = max(0.1, ttl / 4)
        # Stop driving this long before the leases could be someone else's (a quarter of a
        # lease, at least FENCE_MARGIN_MIN, at most half of it).
        self.margin = min(ttl / 2, max(ttl / 4, FENCE_MARGIN_MIN))
        # A transaction of this server that holds lease rows gives them back after this much
        # silence from it (PostgreSQL ends it): a cut-off server locks nobody out for long.
        self.lock_limit = ttl / 2
        self.fenced = False  # stopped driving until a renewal comes back in time
        self.fences = 0
        self.serving: set[str] = set()  # machines whose task runs here (and the duties)
        self._epochs: dict[str, int] = {}
        self._pending: dict[str, int] = {}  # gained, its jobs not taken over yet -> epoch
        self._tasks: list[asyncio.Task[Any]] = []
        self.listener: Listener | None = None
        self.renewals = 0
        self.renew_failures = 0
        self._asked = time.monotonic()  # when the renewal under way began
        runner.fence = self

    @property
    def server(self) -> str:
        """This server's name."""
        return self.leases.server

    # -- the fence the runner asks ----------------------------------------------------------

    def epoch(self, machine: str) -> int | None:
        """The epoch of this server's live lease on ``machine``; None if it holds none, or
        if the lease could expire within ``margin`` (from any thread: a drip-feed's asks
        before each block it writes)."""
        if self.fenced or machine not in self.serving or machine not in self.leases.held:
            return None
        if time.monotonic() >= self.leases.valid_until - self.margin:
            return None
        return self._epochs.get(machine)

    def health(self) -> dict[str, Any]:
        """The leases as ``/api/health`` shows them."""
        left = self.leases.valid_until - self.margin - time.monotonic()
        serving = sorted(m for m in self.serving if m != LIBRARY)
        return {
            "serving": len(serving),
            "fenced": self.fenced or (bool(self.serving) and left <= 0),
            "valid_for": round(max(0.0, left), 3) if self.leases.held else None,
            "renew_failures": self.renew_failures,
        }

    # -- lifecycle --------------------------------------------------------------------------

    async def start(self) -> None:
        """Join: serve nothing until a renewal grants a lease; listen for notices."""
        self._thread = ThreadPoolExecutor(1, thread_name_prefix="cluster-leases")
        for state in self.machines.machines.values():
            state.served = False
        self.listener = Listener(self.database_url, self._notice, on_reconnect=self._reread)
        self._tasks = [
            asyncio.create_task(self.listener.run(), name="cluster-notices"),
            asyncio.create_task(self._renewing(), name="cluster-leases"),
        ]

    async def stop(self) -> None:
        """Leave: stop serving every machine, then free the leases at once (the others take
        them without waiting for them to expire)."""
        tasks, self._tasks = self._tasks, []
        await cancel_and_wait(*tasks)
        # all at once: a server with hundreds of machines closes their links side by side
        await asyncio.gather(*(self._lose(m, SERVER_STOPPED) for m in sorted(self.serving)))
        try:
            await asyncio.to_thread(self.leases.release_all)
        except Exception as exc:
            if not database_down(exc):
                raise
            log.warning("leases not freed (the database is away): they expire by themselves")
        self._thread.shutdown(wait=False)

    def view(self) -> ClusterView:
        """Servers, heartbeats and leases as the database sees them now (blocking)."""
        return cluster_view(self.leases.sessions)

    # -- renewals ---------------------------------------------------------------------------

    async def _renewing(self) -> None:
        loop = asyncio.get_running_loop()
        while True:
            began = time.monotonic()
            # On a thread of its own: behind hundreds of machines' blocking calls in the
            # shared pool, a renewal could wait longer than the lease lasts.
            renewal = loop.run_in_executor(self._thread, self._renew)
            try:
                holding = await self._within_the_lease(renewal)
            except Exception as exc:
                self.renew_failures += 1
                if not database_down(exc):
                    log.exception("renewing the leases failed")
                else:
                    log.warning("leases not renewed: %s", reason(exc))
                if time.monotonic() >= self.leases.valid_until - self.margin:
                    await self._fence("leases may have expired")
            else:
                if time.monotonic() >= holding.valid_until - self.margin:
                    # It came back, but too late to drive anything on it: the next one may
                    # not (a database that answers slowly is as good as a silent one here).
                    self.renew_failures += 1
                    took = time.monotonic() - began
                    await self._fence(f"leases may have expired (a renewal took {took:.1f} s)")
                else:
                    self.renewals += 1
                    self.fenced = False
                    try:
                        await self._apply(holding)
                    except Exception:  # one bad round must not end the renewals
                        log.exception("acting on the leases failed")
            await self._pause(began + self.renew_every)

    async def _pause(self, until: float) -> None:
        """Sleep until the next renewal is due, stopping the machines on the way if the
        leases could expire first (a refused renewal comes back at once; its retry waits)."""
        now = time.monotonic()
        if self.serving and not self.fenced:
            deadline = self.leases.valid_until - self.margin
            if deadline < until:
                await asyncio.sleep(max(0.0, deadline - now))
                await self._fence("leases may have expired")
                now = time.monotonic()
        await asyncio.sleep(max(0.0, until - now))

    async def _within_the_lease(self, renewal: asyncio.Future[Holding]) -> Holding:
        """The renewal's result. While it does not come (a database that went silent: no
        error, no answer), stop driving the machines ``margin`` before the leases could be
        another server's, then go on waiting for the same renewal: a stuck one is not joined
        by a second."""
        while True:
            wait = None
            if self.serving and not self.fenced:
                wait = self.leases.valid_until - self.margin - time.monotonic()
                if wait <= 0:
                    silent = time.monotonic() - self._asked
                    await self._fence(
                        f"leases may have expired (no answer from the database for {silent:.1f} s)"
                    )
                    continue
            done, _ = await asyncio.wait({renewal}, timeout=wait)
            if done:
                return renewal.result()

    async def _fence(self, why: str) -> None:
        """Stop driving every machine now: the runner writes no further block (``epoch``
        answers None from here), a drip-feed gets a moment to stop at its block boundary,
        then every machine's task stops and its link closes."""
        self.fenced = True
        self._epochs = {}
        serving = sorted(self.serving)
        self.leases.held = frozenset()
        if not serving:
            return
        self.fences += 1
        log.warning("%s: serving no machine until renewed", why)
        try:
            # a feed that writes stops at its next line by itself; most of the margin is
            # spent waiting for that, since a link closed under a writing feed may leave the
            # control one block further than the feed could report
            await self.runner.wait_stopped(serving, timeout=min(1.0, self.margin / 2))
            # a feed held by the control's XOFF stops by itself as it waits (it asks before
            # each wait); its link is closed under it all the same, should its thread lag
            await self.runner.stop_runs(serving, timeout=min(0.5, self.margin / 4))
            self.runner.fence_off(serving)  # one whose link would not close: its last line
            # all at once: a server with hundreds of machines closes their links side by side
            why_lost = f"{self.server} cannot reach the database; another server takes over"
            await asyncio.gather(*(self._lose(m, why_lost) for m in serving))
        except Exception:
            log.exception("stopping the machines of expired leases failed")

    def _renew(self) -> Holding:
        self._asked = time.monotonic()
        return self.leases.renew(can_hand_over=self._idle, lock_limit=self.lock_limit)

    def _idle(self, machine: str) -> bool:
        """A machine may be handed over now: no job runs or is being claimed there (the lease
        code checks the database for a running job as well). From the renewal's thread."""
        return machine.startswith("@") or not self.runner.busy(machine)

    async def _apply(self, holding: Holding) -> None:
        self._epochs = dict(holding.epochs)
        for machine in sorted(holding.lost):
            self._pending.pop(machine, None)
            if machine in self.serving:
                await self._lose(machine, f"{self.server} handed this machine to another server")
        # Every held machine not served here yet: gained now, or again after a fence (which
        # may have raced a renewal's own idea of what was gained).
        for machine in sorted(holding.held - self.serving):
            self._pending[machine] = holding.epochs[machine]
        due = {
            m: e for m, e in self._pending.items() if m in holding.held and m not in self.serving
        }
        self._pending.clear()
        if not due:
            return
        try:
            # one transaction for all of them: a server taking 500 machines at once must not
            # spend its lease on 500 round trips
            await self.runner.take_over({m: e for m, e in due.items() if m != LIBRARY})
        except Exception as exc:
            if not database_down(exc):
                raise
            log.warning("jobs of %d machines not taken over yet (database away)", len(due))
            self._pending.update(due)  # the next renewal tries again
            return
        for machine, epoch in sorted(due.items()):
            await self._gain(machine, epoch)

    async def _gain(self, machine: str, epoch: int) -> None:
        if machine == LIBRARY:
            await self.duty.hold()
            self.serving.add(machine)
            log.info("%s runs the shop-wide duties (library watcher, net share)", self.server)
            return
        state = self.machines.machines.get(machine)
        if state is None:
            return
        state.served = True
        state.job_id, state.job_progress = None, (0, None)  # a status row's, not this task's
        if state.last_error == ORPHANED:
            # this server's word while nobody served it, not the link's: it is served now
            state.last_error = ""
        self.serving.add(machine)
        self.machines.bus.publish(LeaseChanged(machine, self.server, True, epoch))
        self.fleet.serve(machine)

    async def _lose(self, machine: str, reason: str) -> None:
        self.serving.discard(machine)
        if machine == LIBRARY:
            try:
                await self.duty.release()
            except Exception:  # the lease goes all the same: never two holders' duties
                log.exception("stopping the shop-wide duties failed")
            return
        state = self.machines.machines.get(machine)
        if state is not None:
            state.served = False
        await self.fleet.release(machine)
        # the outputs say the machine is no longer served from here, and why
        self.machines.bus.publish(LeaseChanged(machine, self.server, False, 0, reason))

    # -- notices ----------------------------------------------------------------------------

    def _notice(self, notice: Notice) -> None:
        match notice.topic:
            case Topic.JOB:
                if notice.key in self.serving:
                    self.machines.wake(notice.key)
            case Topic.CANCEL:
                with contextlib.suppress(ValueError):
                    self.runner.cancel_now(int(notice.key))
            case Topic.LIBRARY:
                number, _, name = notice.key.partition(":")
                version = int(number) if number.isdigit() else None
                self.machines.bus.publish(ProgramChanged(name, version, "cluster"))
            case Topic.STATUS:
                self.on_status(notice.key)
            case None:
                pass  # a topic this server does not know (a newer one's): a hint, not news

    def _reread(self) -> None:
        # notices sent while the listener was away are lost: look at every queue again
        for machine in self.serving:
            self.machines.wake(machine)
        self.on_status("")
