"""The server's small core: components with an async start and stop, run in dependency order.

Each part of the running server (the machine tasks, the job runner and its executors, remote
requests, auto-receive, the library watcher, the net share, DPRNT capture, the loop watch, the
outputs) is a :class:`Component`: a name, the names it ``needs``, ``start()`` and ``stop()``.
:class:`Core` starts them so that every component starts after what it needs, and stops them
in the reverse order, each stop bounded by what is left of one deadline, so a stop that hangs
cannot keep the process alive (docs/server.md#shape-components-and-kinds).

Routes get components through typed FastAPI dependencies (:func:`provide`): the app carries one
:class:`Core`, a route names the component class it wants and gets that type.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol, TypeVar, runtime_checkable

# Starlette's Request is FastAPI's, and resolves provide()'s annotation at run time; FastAPI's
# app module itself would load all of FastAPI for the commands that only use the store.
from starlette.requests import Request

from opendnc.errors import DncError

if TYPE_CHECKING:
    from fastapi import FastAPI

__all__ = [
    "Component",
    "ComponentError",
    "Core",
    "Duty",
    "DutyFlag",
    "RunsTask",
    "StopReport",
    "core_of",
    "provide",
]

log = logging.getLogger(__name__)

STOP_DEADLINE = 10.0  # seconds a whole stop may take (SIGTERM, SIGINT, the end of a test)
RESERVE = 0.2  # seconds kept for each component still to stop after the one stopping


class ComponentError(DncError):
    """A component is missing, named twice, or needs one that is not there."""


@runtime_checkable
class Component(Protocol):
    """A part of the running server."""

    name: str
    needs: tuple[str, ...]

    async def start(self) -> None:
        """Start (return once the component is ready; long work goes into its own tasks)."""

    async def stop(self) -> None:
        """Stop and release what it holds (the core bounds the time this may take)."""


async def cancel_and_wait(*tasks: asyncio.Task[Any]) -> None:
    """Cancel ``tasks`` and wait until each has ended (its errors are logged, not raised).

    A task that swallows one cancel (Python 3.11's ``wait_for`` can, when the awaited result
    arrives in the same moment) is cancelled again, so this returns once they are all done;
    callers bound it with a timeout.
    """
    pending = {t for t in tasks if not t.done()}
    while pending:
        for task in pending:
            task.cancel()
        _done, pending = await asyncio.wait(pending, timeout=0.5)
    for task in tasks:
        if not task.cancelled() and task.exception() is not None:
            log.error("task %s ended with %r", task.get_name(), task.exception())


class RunsTask:
    """Mixin for a component whose work is its :meth:`run` coroutine, from start to stop."""

    name: str
    needs: tuple[str, ...] = ()
    _task: asyncio.Task[None] | None = None

    async def run(self) -> None:
        """The component's work, until cancelled."""
        raise NotImplementedError

    async def start(self) -> None:
        """Start :meth:`run` as a task."""
        self._task = asyncio.create_task(self._guarded(), name=self.name)

    async def _guarded(self) -> None:
        try:
            await self.run()
        except asyncio.CancelledError:
            raise
        except Exception:  # one part's bug must not take the server down, nor pass silently
            log.exception("%s stopped by an error", self.name)

    async def stop(self) -> None:
        """Cancel the task and wait for it."""
        task, self._task = self._task, None
        if task is not None:
            await cancel_and_wait(task)


class DutyFlag:
    """Whether this server runs the shop-wide duties now (the library watcher, the net share).

    A server alone holds it from the start; in a cluster, the cluster raises it while it holds
    the duties' lease and lowers it when it loses it. The duties are components of the core
    (:class:`Duty`): the core starts and stops them, the flag says whether they work. Raising
    or lowering it returns once every started duty followed, so a cluster gives the lease away
    only after its duties stopped.
    """

    def __init__(self, held: bool) -> None:
        self.held = held
        self._duties: list[Duty] = []

    async def hold(self) -> None:
        """Run the duties (each started duty starts its work; those started later, at once)."""
        self.held = True
        for duty in list(self._duties):
            await duty.follow()

    async def release(self) -> None:
        """Stop the duties' work (in reverse order), returning once each has stopped."""
        self.held = False
        for duty in reversed(list(self._duties)):
            try:
                await duty.follow()
            except Exception:  # one duty's failed stop must not keep the next one running
                log.exception("%s failed to stop", duty.name)


class Duty:
    """A component whose work runs only while its :class:`DutyFlag` is held.

    It bears the name and the needs of the part it runs (``inner``), and :meth:`Core.get`
    finds it by that part's class: ``core.get(LibraryWatcher)`` is the watcher, on duty or not.
    """

    def __init__(self, inner: Component, flag: DutyFlag) -> None:
        self.inner = inner
        self.flag = flag
        self.name = inner.name
        self.needs = inner.needs
        self._started = False  # by the core
        self._working = False  # the inner part runs
        self._lock = asyncio.Lock()  # the core's start or stop and the flag's change, in turn

    @property
    def working(self) -> bool:
        """Whether the inner part runs now."""
        return self._working

    async def start(self) -> None:
        """Join the flag; start the inner part if the flag is held."""
        self._started = True
        self.flag._duties.append(self)
        await self.follow()

    async def stop(self) -> None:
        """Leave the flag; stop the inner part if it runs."""
        self._started = False
        with contextlib.suppress(ValueError):
            self.flag._duties.remove(self)
        await self.follow()

    async def follow(self) -> None:
        """Start or stop the inner part to match the core and the flag."""
        async with self._lock:
            wanted = self._started and self.flag.held
            if wanted and not self._working:
                await self.inner.start()
                self._working = True
            elif not wanted and self._working:
                self._working = False
                await self.inner.stop()


@dataclass(frozen=True)
class StopReport:
    """How a stop went: seconds per component, and the ones cut off at their deadline."""

    seconds: dict[str, float]
    timed_out: tuple[str, ...]


C = TypeVar("C")


class Core:
    """Registered components, started in dependency order and stopped in reverse."""

    def __init__(self) -> None:
        self._components: dict[str, Component] = {}
        self._started: list[Component] = []

    def add(self, component: C) -> C:
        """Register ``component`` (a :class:`Component`); returns it, typed."""
        if not isinstance(component, Component):
            raise ComponentError(f"{component!r} is not a component")
        if component.name in self._components:
            raise ComponentError(f"two components named {component.name!r}")
        self._components[component.name] = component
        return component

    def get(self, kind: type[C]) -> C:
        """The one registered component of class ``kind`` (a :class:`Duty`'s part by its own)."""
        found = self._of(kind)
        if len(found) != 1:
            raise ComponentError(f"{len(found)} components of type {kind.__name__}, not one")
        return found[0]

    def find(self, kind: type[C]) -> C | None:
        """The registered component of class ``kind``, or None (optional parts: outputs)."""
        found = self._of(kind)
        return found[0] if len(found) == 1 else None

    def _of(self, kind: type[C]) -> list[C]:
        found: list[C] = []
        for component in self._components.values():
            part = component.inner if isinstance(component, Duty) else component
            if isinstance(component, kind):
                found.append(component)
            elif isinstance(part, kind):
                found.append(part)
        return found

    def __iter__(self) -> Iterator[Component]:
        return iter(self.order())

    def states(self) -> dict[str, str]:
        """Each component's name and whether it runs now ("running" or "stopped")."""
        started = {c.name for c in self._started}
        return {c.name: "running" if c.name in started else "stopped" for c in self.order()}

    def order(self) -> list[Component]:
        """Every component after the ones it needs. Only the declared needs order them: the
        components are taken by name, so the order of registration makes no difference."""
        done: dict[str, Component] = {}
        visiting: set[str] = set()

        def visit(component: Component) -> None:
            if component.name in done:
                return
            if component.name in visiting:
                raise ComponentError(f"components need each other: {component.name}")
            visiting.add(component.name)
            for need in component.needs:
                if need not in self._components:
                    raise ComponentError(f"{component.name} needs {need}, which is not there")
                visit(self._components[need])
            visiting.discard(component.name)
            done[component.name] = component

        for name in sorted(self._components):
            visit(self._components[name])
        return list(done.values())

    async def start(self) -> None:
        """Start every component in order; if one fails, stop those started and re-raise."""
        for component in self.order():
            try:
                await component.start()
            except BaseException:
                await self.stop()
                raise
            self._started.append(component)
            log.debug("started %s", component.name)

    async def stop(self, deadline: float = STOP_DEADLINE) -> StopReport:
        """Stop the started components in reverse order within ``deadline`` seconds in all.

        Each stop may take what is left of the deadline but :data:`RESERVE` seconds for each
        component after it (at least that much itself): most stops take no time, one may need
        many seconds (the machines' links closing), and one that hangs is cut off (cancelled)
        and named in the report while the next still stops.
        """
        end = time.monotonic() + deadline
        seconds: dict[str, float] = {}
        timed_out: list[str] = []
        started, self._started = self._started, []
        for index, component in enumerate(reversed(started)):
            after = len(started) - index - 1
            share = max(RESERVE, end - time.monotonic() - RESERVE * after)
            began = time.monotonic()
            try:
                async with asyncio.timeout(share):
                    await component.stop()
            except TimeoutError:
                timed_out.append(component.name)
                log.warning(
                    "%s took more than its %.1f s to stop; left behind", component.name, share
                )
            except Exception:
                log.exception("%s failed to stop", component.name)
            seconds[component.name] = time.monotonic() - began
        took = deadline - (end - time.monotonic())
        if took > deadline / 2:
            slow = sorted(seconds.items(), key=lambda kv: -kv[1])[:3]
            log.warning(
                "stopping took %.1f s (%s)", took, ", ".join(f"{n} {s:.1f} s" for n, s in slow)
            )
        return StopReport(seconds, tuple(timed_out))


def core_of(app: FastAPI) -> Core:
    """The :class:`Core` an app was built with."""
    core = app.state.core
    if not isinstance(core, Core):
        raise ComponentError("the app has no components (build it with opendnc.server.app)")
    return core


def provide(kind: type[C]) -> Callable[[Request], C]:
    """A FastAPI dependency that hands a route the app's component of class ``kind``:
    ``Runner = Annotated[JobRunner, Depends(provide(JobRunner))]``."""

    def dependency(request: Request) -> C:
        return core_of(request.app).get(kind)

    dependency.__name__ = f"provide_{kind.__name__}"
    return dependency


@contextlib.asynccontextmanager
async def running(core: Core, deadline: float = STOP_DEADLINE) -> Any:
    """Start ``core``'s components for the ``async with`` block; stop them at its end."""
    await core.start()
    try:
        yield core
    finally:
        await core.stop(deadline)
