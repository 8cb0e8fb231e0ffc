"""The server's core: components start after what they need, stop in reverse, and a stop that
hangs is cut off at its share of the deadline while the others still stop."""

from __future__ import annotations

import asyncio
import time
from pathlib import Path

import pytest

from tests.peers import require_module

require_module("fastapi")

from opendnc.server.core.components import (  # noqa: E402
    ComponentError,
    Core,
    Duty,
    DutyFlag,
    RunsTask,
    cancel_and_wait,
)


class Part:
    def __init__(self, name: str, log: list[str], *needs: str, hang: bool = False) -> None:
        self.name = name
        self.needs = needs
        self.log = log
        self.hang = hang

    async def start(self) -> None:
        self.log.append(f"start {self.name}")

    async def stop(self) -> None:
        self.log.append(f"stop {self.name}")
        if self.hang:
            await asyncio.Event().wait()  # never set: only the deadline ends this


def test_components_start_after_their_needs_and_stop_in_reverse() -> None:
    log: list[str] = []
    core = Core()
    # registered out of order on purpose
    core.add(Part("fleet", log, "runner", "machines"))
    core.add(Part("runner", log, "machines"))
    core.add(Part("machines", log))
    core.add(Part("timeline", log, "fleet"))

    async def run() -> None:
        await core.start()
        await core.stop()

    asyncio.run(run())
    assert log == [
        "start machines",
        "start runner",
        "start fleet",
        "start timeline",
        "stop timeline",
        "stop fleet",
        "stop runner",
        "stop machines",
    ]


def test_a_hanging_stop_is_cut_off_and_the_rest_still_stop_within_the_deadline() -> None:
    log: list[str] = []
    core = Core()
    core.add(Part("machines", log))
    core.add(Part("stuck", log, "machines", hang=True))
    core.add(Part("outputs", log, "stuck"))

    async def run() -> tuple[float, tuple[str, ...]]:
        await core.start()
        began = time.monotonic()
        report = await core.stop(deadline=1.5)
        return time.monotonic() - began, report.timed_out

    took, timed_out = asyncio.run(run())
    assert timed_out == ("stuck",)
    assert log[-3:] == ["stop outputs", "stop stuck", "stop machines"]
    assert took < 1.5 + 0.5


def test_a_start_that_fails_stops_what_had_started() -> None:
    log: list[str] = []

    class Broken(Part):
        async def start(self) -> None:
            raise RuntimeError("no")

    core = Core()
    core.add(Part("machines", log))
    core.add(Broken("broken", log, "machines"))
    with pytest.raises(RuntimeError):
        asyncio.run(core.start())
    assert log == ["start machines", "stop machines"]


def test_needs_that_are_missing_or_circular_are_named() -> None:
    core = Core()
    core.add(Part("a", [], "b"))
    with pytest.raises(ComponentError, match="a needs b"):
        core.order()
    core.add(Part("b", [], "a"))
    with pytest.raises(ComponentError, match="need each other"):
        core.order()
    with pytest.raises(ComponentError, match="two components named"):
        core.add(Part("a", []))


def test_typed_lookup_finds_the_one_component_of_a_class() -> None:
    core = Core()
    part = core.add(Part("machines", []))
    assert core.get(Part) is part
    assert core.find(RunsTask) is None
    with pytest.raises(ComponentError):
        core.get(RunsTask)


def test_a_task_that_swallows_a_cancel_is_cancelled_again() -> None:
    swallowed = []

    async def stubborn() -> None:
        try:
            await asyncio.sleep(60)
        except asyncio.CancelledError:
            swallowed.append(True)  # what wait_for can do on 3.11: carry on regardless
        await asyncio.sleep(60)

    async def run() -> float:
        task = asyncio.create_task(stubborn())
        await asyncio.sleep(0.05)
        began = time.monotonic()
        await cancel_and_wait(task)
        assert task.cancelled()
        return time.monotonic() - began

    assert asyncio.run(run()) < 2.0
    assert swallowed == [True]


def _started_order(parts: list[Part], log: list[str]) -> list[str]:
    core = Core()
    for part in parts:
        core.add(part)

    async def run() -> None:
        await core.start()
        await core.stop()

    asyncio.run(run())
    return [line.removeprefix("start ") for line in log if line.startswith("start ")]


def test_start_order_follows_the_declared_needs_alone() -> None:
    # the server's own shape: the fleet needs the timeline, which nothing else orders
    needs = {
        "database": (),
        "machines": (),
        "runner": ("machines", "database"),
        "outputs": ("machines",),
        "timeline": ("machines", "database"),
        "fleet": ("machines", "runner", "outputs", "timeline"),
        "cluster": ("fleet", "runner"),
        "library-watcher": ("database", "machines"),
    }
    names = list(needs)
    orders = []
    for registration in (names, names[::-1], names[3:] + names[:3], sorted(names)):
        log: list[str] = []
        started = _started_order([Part(n, log, *needs[n]) for n in registration], log)
        for name, wanted in needs.items():
            for need in wanted:
                assert started.index(need) < started.index(name), (registration, started)
        orders.append(started)
    # the registration order makes no difference at all, not just none that breaks a need
    assert all(order == orders[0] for order in orders)


def test_a_component_that_needs_an_unregistered_one_cannot_start() -> None:
    log: list[str] = []
    core = Core()
    core.add(Part("machines", log))
    core.add(Part("fleet", log, "machines", "timeline"))
    with pytest.raises(ComponentError, match="fleet needs timeline"):
        asyncio.run(core.start())
    assert log == []  # nothing started on a half-declared server


def test_a_duty_works_while_its_flag_is_held_and_the_core_runs_it() -> None:
    log: list[str] = []
    flag = DutyFlag(held=False)
    core = Core()
    core.add(Part("machines", log))
    watcher = Part("watcher", log, "machines")
    duty = core.add(Duty(watcher, flag))

    async def run() -> None:
        await core.start()
        assert log == ["start machines"]  # registered and started, not working: not held
        await flag.hold()
        assert log[-1] == "start watcher"
        assert duty.working
        await flag.release()
        assert log[-1] == "stop watcher"
        assert not duty.working
        await flag.hold()
        await core.stop()  # the core's stop ends its work though the flag is still held

    asyncio.run(run())
    assert log[-3:] == ["start watcher", "stop watcher", "stop machines"]


def test_a_duty_is_found_by_the_class_of_its_part() -> None:
    class Watcher(Part):
        pass

    core = Core()
    watcher = Watcher("watcher", [])
    core.add(Duty(watcher, DutyFlag(held=True)))
    assert core.get(Watcher) is watcher


def test_the_built_server_starts_each_part_after_what_it_needs_in_any_registration_order(
    tmp_path: Path,
) -> None:
    """The server as build() makes it (alerts and the net share on): its start order holds
    the needs the parts rely on, and registering its parts in reverse changes nothing."""
    from opendnc.server.app import build
    from opendnc.server.config.shop import parse_config
    from tests.server.inprocess_app import config_text

    (tmp_path / "nas").mkdir()
    extra = (
        '[alerts]\n[[alerts.webhooks]]\nname = "w"\nurl = "http://127.0.0.1:9/x"\n'
        '[[alerts.rules]]\nname = "long-stop"\nwhen = "stopped"\nminutes = 10\n'
        f'[netshare]\npath = "{tmp_path / "nas"}"\n'
    )
    (tmp_path / "share").mkdir()
    haas = {
        "name": "vf2",
        "kind": "haas_ngc",
        "host": "127.0.0.1",
        "share": str(tmp_path / "share"),
    }
    text = extra + config_text(tmp_path, [haas])
    server = build(parse_config(text, base=tmp_path), database=f"sqlite:///{tmp_path / 'db'}")
    try:
        order = [c.name for c in server.core.order()]
        before = {name: set(order[: order.index(name)]) for name in order}
        # the machines' first status finds every listener subscribed, the timeline among them
        assert {"timeline", "outputs", "alerts", "runner"} <= before["fleet"]
        # the duties are the core's components, after the policy their gate asks
        assert {"database", "machines", "actions"} <= before["netshare"]
        assert {"database", "machines"} <= before["library-watcher"]
        reverse = Core()
        for component in reversed(list(server.core._components.values())):
            reverse.add(component)
        assert [c.name for c in reverse.order()] == order
    finally:
        server.engine.dispose()
